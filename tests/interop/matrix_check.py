#!/usr/bin/env python3
"""Checks the stdout of a peer's subscribe-state / subscribe-task run (used by
peer_matrix.sh). Exits non-zero, with the reason on stderr, on any mismatch.

  matrix_check.py state <stdout-file> --vehicle-id ID --count N --vendor V
  matrix_check.py task  <stdout-file> --vehicle-id ID --task-id T
"""

import argparse
import json
import math
import sys

STATE_FIELDS = ["vehicle_id", "timestamp_ms", "latitude_deg", "longitude_deg", "depth_m",
                "altitude_m", "speed_mps", "yaw_deg", "pitch_deg", "roll_deg", "battery_pct"]
ANN_FIELDS = ["vehicle_id", "name", "kind", "vendor", "capabilities", "sensors", "links",
              "max_speed_mps", "timestamp_ms"]
TASK_FIELDS = ["task_id", "mission_id", "vehicle_id", "issued_ms", "kind", "area", "depth_m",
               "altitude_m", "speed_mps", "line_spacing_m", "duration_s", "rate_hz", "issue_seq", "expires_ms",
               "lease_term", "lease_holder"]


class Fail(Exception):
    pass


def close(a, b):
    return isinstance(a, (int, float)) and math.isclose(a, b, rel_tol=0, abs_tol=1e-9)


def expect(cond, msg):
    if not cond:
        raise Fail(msg)


def plausible_now(ms):
    # 2020-01-01 .. 2100-01-01
    return isinstance(ms, int) and 1577836800000 <= ms <= 4102444800000


def check_state(lines, a):
    anns = [json.loads(l[len("announcement "):]) for l in lines if l.startswith("announcement ")]
    states = [json.loads(l) for l in lines if l.startswith("{")]
    expect(len(anns) >= 1, "no VehicleAnnouncement received")
    ann = anns[0]
    expect(list(ann) == ANN_FIELDS, f"announcement members/order: {list(ann)}")
    expect(ann["vehicle_id"] == a.vehicle_id, f"announcement vehicle_id {ann['vehicle_id']!r}")
    expect(ann["vendor"] == a.vendor, f"announcement vendor {ann['vendor']!r} != {a.vendor!r}")
    expect(ann["kind"] == "AUV", f"announcement kind {ann['kind']!r}")
    expect(ann["capabilities"] == ["goto", "survey"], f"capabilities {ann['capabilities']!r}")
    expect(ann["sensors"] == ["ctd"], f"sensors {ann['sensors']!r}")
    expect(ann["links"] == ["IP"], f"links {ann['links']!r}")
    expect(close(ann["max_speed_mps"], 2.0), f"max_speed_mps {ann['max_speed_mps']!r}")
    expect(plausible_now(ann["timestamp_ms"]), f"announcement timestamp_ms {ann['timestamp_ms']!r}")

    expect(len(states) == a.count, f"{len(states)} StateVectors, expected {a.count}")
    for i, s in enumerate(states):
        expect(list(s) == STATE_FIELDS, f"state members/order: {list(s)}")
        expect(s["vehicle_id"] == a.vehicle_id, f"state {i}: vehicle_id {s['vehicle_id']!r}")
        expect(plausible_now(s["timestamp_ms"]), f"state {i}: timestamp_ms {s['timestamp_ms']!r}")
        want = {"latitude_deg": 43.0 + i * 1e-5, "longitude_deg": 5.9, "depth_m": 10.0,
                "altitude_m": -1.0, "speed_mps": 1.0, "yaw_deg": 90.0, "pitch_deg": 0.0,
                "roll_deg": 0.0, "battery_pct": 90.0 - i * 0.01}
        for k, v in want.items():
            expect(close(s[k], v), f"state {i}: {k} = {s[k]!r}, expected {v!r} (order or encoding?)")
    return f"{len(states)} StateVectors + announcement from {ann['vendor']}"


def check_task(lines, a):
    tasks = [json.loads(l) for l in lines if l.startswith("{")]
    expect(len(tasks) == 1, f"{len(tasks)} TaskAssignments, expected 1")
    t = tasks[0]
    expect(list(t) == TASK_FIELDS, f"task members/order: {list(t)}")
    expect(t["task_id"] == a.task_id, f"task_id {t['task_id']!r}")
    expect(t["vehicle_id"] == a.vehicle_id, f"vehicle_id {t['vehicle_id']!r}")
    expect(t["mission_id"] == "", f"mission_id {t['mission_id']!r}")
    expect(t["kind"] == "GOTO_WAYPOINT", f"kind {t['kind']!r}")
    expect(plausible_now(t["issued_ms"]), f"issued_ms {t['issued_ms']!r}")
    expect(len(t["area"]) == 1 and close(t["area"][0]["latitude_deg"], 43.0)
           and close(t["area"][0]["longitude_deg"], 5.9), f"area {t['area']!r}")
    want = {"depth_m": 10.0, "altitude_m": -1.0, "speed_mps": 1.5, "line_spacing_m": 0.0,
            "duration_s": 0.0, "rate_hz": 0.0}
    for k, v in want.items():
        expect(close(t[k], v), f"{k} = {t[k]!r}, expected {v!r}")
    # The peers publish as a station without a command lease.
    expect(t["lease_term"] == 0, f"lease_term {t['lease_term']!r}, expected 0")
    expect(t["lease_holder"] == "", f"lease_holder {t['lease_holder']!r}, expected ''")
    return f"task {t['task_id']} ({t['kind']})"


def main():
    p = argparse.ArgumentParser()
    p.add_argument("what", choices=["state", "task"])
    p.add_argument("file")
    p.add_argument("--vehicle-id", required=True)
    p.add_argument("--count", type=int, default=1)
    p.add_argument("--vendor", default="")
    p.add_argument("--task-id", default="")
    a = p.parse_args()
    with open(a.file, encoding="utf-8") as f:
        lines = [l.strip() for l in f if l.strip()]
    try:
        msg = (check_state if a.what == "state" else check_task)(lines, a)
    except (Fail, ValueError, KeyError, TypeError) as e:
        print(f"matrix_check: {a.what}: {e}", file=sys.stderr)
        return 1
    print(msg)
    return 0


if __name__ == "__main__":
    sys.exit(main())
