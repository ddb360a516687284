"""Shared command-line interface and sample contents for Shoal's Python DDS peers.

Every foreign peer (cyclone_peer.py, rti_peer.py and the Fast DDS C++ peer)
exposes the same subcommands and prints the same machine-readable lines on
stdout; logs go to stderr. Samples are exchanged here as plain dicts whose keys
are the IDL member names (in IDL order) and whose enum values are the IDL
enumerator names, e.g. {"kind": "GOTO_WAYPOINT", ...}.
"""

import argparse
import json
import signal
import sys
import time

# Topic names and module-qualified type names, exactly as in idl/shoal.idl.
TOPIC_STATE = "shoal/state_vector"
TOPIC_ANNOUNCEMENT = "shoal/vehicle_announcement"
TOPIC_TASK = "shoal/task_assignment"
TOPIC_TASK_STATUS = "shoal/task_status"
TOPIC_EVENT = "shoal/event"
TOPIC_ENVIRONMENT = "shoal/environment"

TYPE_STATE = "shoal::StateVector"
TYPE_ANNOUNCEMENT = "shoal::VehicleAnnouncement"
TYPE_TASK = "shoal::TaskAssignment"

# Enumerators in IDL order (ordinal = index).
VEHICLE_KIND = ["AUV", "USV", "ASV", "ROV", "GLIDER"]
LINK_KIND = ["IP", "ACOUSTIC", "RADIO", "SATELLITE", "TETHER"]
TASK_KIND = ["GOTO_WAYPOINT", "SURVEY_AREA", "HOLD", "SURFACE", "RETURN_HOME",
             "ABORT", "REQUEST_STATE", "SET_REPORTING_RATE"]

MATCH_TIMEOUT_S = 20.0


def now_ms() -> int:
    return int(time.time() * 1000)


def log(peer: str, msg: str) -> None:
    print(f"[{peer}] {msg}", file=sys.stderr, flush=True)


def emit(line: str) -> None:
    """A machine-readable line on stdout."""
    print(line, flush=True)


def emit_json(sample: dict) -> None:
    emit(json.dumps(sample, separators=(",", ":")))


def announcement(vehicle_id: str, vendor: str) -> dict:
    return {
        "vehicle_id": vehicle_id,
        "name": f"{vendor} interop vehicle {vehicle_id}",
        "kind": "AUV",
        "vendor": vendor,
        "capabilities": ["goto", "survey"],
        "sensors": ["ctd"],
        "links": ["IP"],
        "max_speed_mps": 2.0,
        "timestamp_ms": now_ms(),
    }


def state_vector(vehicle_id: str, i: int) -> dict:
    return {
        "vehicle_id": vehicle_id,
        "timestamp_ms": now_ms(),
        "latitude_deg": 43.0 + i * 1e-5,
        "longitude_deg": 5.9,
        "depth_m": 10.0,
        "altitude_m": -1.0,
        "speed_mps": 1.0,
        "yaw_deg": 90.0,
        "pitch_deg": 0.0,
        "roll_deg": 0.0,
        "battery_pct": 90.0 - i * 0.01,
    }


def goto_task(task_id: str, vehicle_id: str) -> dict:
    return {
        "task_id": task_id,
        "mission_id": "",
        "vehicle_id": vehicle_id,
        "issued_ms": now_ms(),
        "kind": "GOTO_WAYPOINT",
        "area": [{"latitude_deg": 43.0, "longitude_deg": 5.9}],
        "depth_m": 10.0,
        "altitude_m": -1.0,
        "speed_mps": 1.5,
        "line_spacing_m": 0.0,
        "duration_s": 0.0,
        "rate_hz": 0.0,
        "issue_seq": 1,
        "expires_ms": now_ms() + 600_000,
        # Sent as a station without a command lease would (no federation, or the lease off).
        "lease_term": 0,
        "lease_holder": "",
    }


class Stop:
    """Set by SIGINT/SIGTERM; loops poll it and exit cleanly."""

    flag = False
    code = 130  # exit code after a signal: 128 + signal number

    @classmethod
    def install(cls) -> None:
        def handler(signum, _frame):
            cls.flag = True
            cls.code = 128 + signum
        signal.signal(signal.SIGINT, handler)
        signal.signal(signal.SIGTERM, handler)


def sleep_unless_stopped(seconds: float) -> bool:
    """Sleep in small steps; returns False if a stop signal arrived."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if Stop.flag:
            return False
        time.sleep(min(0.05, max(0.0, end - time.monotonic())))
    return not Stop.flag


def parser(prog: str, extra=None) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description="Shoal interop DDS peer")
    p.add_argument("--domain", type=int, default=0, help="DDS domain id (default 0)")
    sub = p.add_subparsers(dest="cmd", required=True)

    s = sub.add_parser("publish-state", help="announce a vehicle, then publish N StateVectors")
    s.add_argument("--domain", type=int, default=argparse.SUPPRESS)
    s.add_argument("--vehicle-id", required=True)
    s.add_argument("--count", type=int, default=10)
    s.add_argument("--rate", type=float, default=10.0, help="samples per second")
    s.add_argument("--linger", type=float, default=3.0, help="seconds to stay up after the last sample")
    s.add_argument("--settle", type=float, default=1.0,
                   help="seconds to wait after the first reader matched before publishing: the "
                        "writer can see the reader before the reader has discovered the writer, and "
                        "a VOLATILE reader drops samples written in that window (default 1)")

    s = sub.add_parser("subscribe-task", help="print TaskAssignments for one vehicle as JSON lines")
    s.add_argument("--domain", type=int, default=argparse.SUPPRESS)
    s.add_argument("--vehicle-id", required=True)
    s.add_argument("--expect", type=int, default=1)
    s.add_argument("--timeout", type=float, default=30.0)

    s = sub.add_parser("publish-task", help="publish one GOTO_WAYPOINT TaskAssignment (transient-local)")
    s.add_argument("--domain", type=int, default=argparse.SUPPRESS)
    s.add_argument("--vehicle-id", required=True)
    s.add_argument("--task-id", required=True)
    s.add_argument("--linger", type=float, default=3.0,
                   help="seconds to stay up after publishing (late joiners get the sample while we live)")
    s.add_argument("--wait-match", type=float, default=0.0,
                   help="first wait up to S seconds for a matched reader (default 0: do not wait)")

    s = sub.add_parser("subscribe-state", help="print StateVectors as JSON lines")
    s.add_argument("--domain", type=int, default=argparse.SUPPRESS)
    s.add_argument("--expect", type=int, default=1)
    s.add_argument("--timeout", type=float, default=30.0)
    s.add_argument("--vehicle-id", default=None, help="only count samples of this vehicle")
    s.add_argument("--expect-announcements", type=int, default=0,
                   help="also read shoal/vehicle_announcement (transient-local) and require K samples; "
                        "each is printed as 'announcement <json>'")

    if extra:
        extra(sub)
    return p
