#!/usr/bin/env python3
"""Shoal interop peer on Eclipse Cyclone DDS (PyPI `cyclonedds`).

Types mirror idl/shoal.idl: module-qualified type names ("shoal::StateVector"),
@final extensibility, @key members, bounded strings and sequences, same member
order. Every reader and writer carries DataRepresentation = [XCDR1] so the
samples on the wire are plain CDR (encapsulation CDR_LE 0x0001), the only
representation Shoal reads.

Subcommands (same interface as rti_peer.py and the Fast DDS peer):
  publish-state  --vehicle-id ID --count N --rate HZ [--linger S]
  subscribe-task --vehicle-id ID --expect N --timeout S
  publish-task   --vehicle-id ID --task-id T [--linger S] [--wait-match S]
  subscribe-state --expect N --timeout S [--vehicle-id ID] [--expect-announcements K]
Extra, no DDS traffic (byte-level checks against the Rust serializer):
  encode-sample <Type> <json> [--header] [--big-endian]   XCDR1 bytes as hex
  decode-sample <Type> <hex>  [--header]                  hex -> JSON
  key-hash      <Type> <json>                             RTPS 16-byte key hash
"""

import dataclasses
import enum
import hashlib
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import peer_common as pc  # noqa: E402

from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.idl import IdlEnum, IdlStruct  # noqa: E402
from cyclonedds.idl._support import Endianness  # noqa: E402
from cyclonedds.idl.annotations import final, key  # noqa: E402
import cyclonedds.idl.types as t  # noqa: E402
from cyclonedds.pub import DataWriter, Publisher  # noqa: E402
from cyclonedds.qos import Policy, Qos  # noqa: E402
from cyclonedds.sub import DataReader, Subscriber  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402
from cyclonedds.util import duration  # noqa: E402

PEER = "cyclonedds"

# ---------------------------------------------------------------- types (IDL)


class VehicleKind(IdlEnum, typename="shoal::VehicleKind"):
    AUV = 0
    USV = 1
    ASV = 2
    ROV = 3
    GLIDER = 4


class LinkKind(IdlEnum, typename="shoal::LinkKind"):
    IP = 0
    ACOUSTIC = 1
    RADIO = 2
    SATELLITE = 3
    TETHER = 4


class Severity(IdlEnum, typename="shoal::Severity"):
    INFO = 0
    WARNING = 1
    ALARM = 2
    CRITICAL = 3


class EventKind(IdlEnum, typename="shoal::EventKind"):
    LOW_BATTERY = 0
    OUT_OF_AREA = 1
    COMM_LOST = 2
    FAULT = 3
    DETECTION = 4
    TASK = 5
    RULE = 6
    DATA_REJECTED = 7
    OTHER = 8


class TaskKind(IdlEnum, typename="shoal::TaskKind"):
    GOTO_WAYPOINT = 0
    SURVEY_AREA = 1
    HOLD = 2
    SURFACE = 3
    RETURN_HOME = 4
    ABORT = 5
    REQUEST_STATE = 6
    SET_REPORTING_RATE = 7


class TaskState(IdlEnum, typename="shoal::TaskState"):
    PENDING = 0
    SENT = 1
    ACCEPTED = 2
    RUNNING = 3
    DONE = 4
    FAILED = 5
    ABORTED = 6
    EXPIRED = 7


@final
@dataclasses.dataclass
class StateVector(IdlStruct, typename="shoal::StateVector"):
    vehicle_id: t.bounded_str[32]
    key("vehicle_id")
    timestamp_ms: t.int64
    latitude_deg: t.float64
    longitude_deg: t.float64
    depth_m: t.float64
    altitude_m: t.float64
    speed_mps: t.float64
    yaw_deg: t.float64
    pitch_deg: t.float64
    roll_deg: t.float64
    battery_pct: t.float64


@final
@dataclasses.dataclass
class VehicleAnnouncement(IdlStruct, typename="shoal::VehicleAnnouncement"):
    vehicle_id: t.bounded_str[32]
    key("vehicle_id")
    name: t.bounded_str[64]
    kind: VehicleKind
    vendor: t.bounded_str[64]
    capabilities: t.sequence[t.bounded_str[64], 32]
    sensors: t.sequence[t.bounded_str[64], 32]
    links: t.sequence[LinkKind, 8]
    max_speed_mps: t.float64
    timestamp_ms: t.int64


@final
@dataclasses.dataclass
class GeoPoint(IdlStruct, typename="shoal::GeoPoint"):
    latitude_deg: t.float64
    longitude_deg: t.float64


@final
@dataclasses.dataclass
class TaskAssignment(IdlStruct, typename="shoal::TaskAssignment"):
    task_id: t.bounded_str[64]
    key("task_id")
    mission_id: t.bounded_str[64]
    vehicle_id: t.bounded_str[32]
    issued_ms: t.int64
    kind: TaskKind
    area: t.sequence[GeoPoint, 256]
    depth_m: t.float64
    altitude_m: t.float64
    speed_mps: t.float64
    line_spacing_m: t.float64
    duration_s: t.float64
    rate_hz: t.float64
    issue_seq: t.uint64
    expires_ms: t.int64
    lease_term: t.uint64
    lease_holder: t.bounded_str[32]


@final
@dataclasses.dataclass
class TaskStatus(IdlStruct, typename="shoal::TaskStatus"):
    task_id: t.bounded_str[64]
    key("task_id")
    vehicle_id: t.bounded_str[32]
    timestamp_ms: t.int64
    state: TaskState
    progress_pct: t.float64
    message: t.bounded_str[512]


@final
@dataclasses.dataclass
class Event(IdlStruct, typename="shoal::Event"):
    event_id: t.bounded_str[64]
    key("event_id")
    timestamp_ms: t.int64
    severity: Severity
    kind: EventKind
    vehicle_id: t.bounded_str[32]
    task_id: t.bounded_str[64]
    text: t.bounded_str[512]


@final
@dataclasses.dataclass
class EnvironmentObservation(IdlStruct, typename="shoal::EnvironmentObservation"):
    vehicle_id: t.bounded_str[32]
    key("vehicle_id")
    property: t.bounded_str[64]
    key("property")
    timestamp_ms: t.int64
    value: t.float64
    unit: t.bounded_str[16]
    latitude_deg: t.float64
    longitude_deg: t.float64
    depth_m: t.float64


TYPES = {c.__name__: c for c in (StateVector, VehicleAnnouncement, GeoPoint, TaskAssignment,
                                 TaskStatus, Event, EnvironmentObservation)}

# Members that are enums or sequences of enums / structs, per type.
CONVERT = {
    "VehicleAnnouncement": {"kind": VehicleKind, "links": [LinkKind]},
    "TaskAssignment": {"kind": TaskKind, "area": [GeoPoint]},
    "TaskStatus": {"state": TaskState},
    "Event": {"severity": Severity, "kind": EventKind},
}


def _conv_one(conv, v):
    if isinstance(conv, type) and issubclass(conv, enum.Enum):
        return conv(v) if isinstance(v, int) else conv[v]
    if isinstance(conv, type) and issubclass(conv, IdlStruct):
        return to_sample(conv, v)
    return v


def to_sample(cls, d: dict):
    """JSON-style dict (enum names, nested dicts) -> IdlStruct instance."""
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = set(d) - set(names)
    if unknown:
        raise ValueError(f"{cls.__name__}: unknown members {sorted(unknown)}")
    missing = [n for n in names if n not in d]
    if missing:
        raise ValueError(f"{cls.__name__}: missing members {missing}")
    conv = CONVERT.get(cls.__name__, {})
    kw = {}
    for n in names:
        v = d[n]
        c = conv.get(n)
        if isinstance(c, list):
            v = [_conv_one(c[0], x) for x in v]
        elif c is not None:
            v = _conv_one(c, v)
        kw[n] = v
    return cls(**kw)


def to_dict(sample) -> dict:
    """IdlStruct instance -> JSON-style dict in IDL member order."""
    def val(v):
        if isinstance(v, enum.Enum):
            return v.name
        if isinstance(v, IdlStruct):
            return to_dict(v)
        if isinstance(v, list):
            return [val(x) for x in v]
        return v
    return {f.name: val(getattr(sample, f.name)) for f in dataclasses.fields(sample)}


# ---------------------------------------------------------------- QoS

XCDR1 = Policy.DataRepresentation(use_cdrv0_representation=True, use_xcdrv2_representation=False)


def qos(durability_transient_local: bool, depth: int) -> Qos:
    return Qos(
        Policy.Reliability.Reliable(max_blocking_time=duration(seconds=1)),
        Policy.Durability.TransientLocal if durability_transient_local else Policy.Durability.Volatile,
        Policy.History.KeepLast(depth),
        XCDR1,
    )


QOS_ANNOUNCEMENT = qos(True, 1)
QOS_STATE = qos(False, 100)
QOS_TASK = qos(True, 100)


class Peer:
    def __init__(self, domain: int):
        self.dp = DomainParticipant(domain)
        self.pub = Publisher(self.dp)
        self.sub = Subscriber(self.dp)

    def writer(self, topic_name, cls, q):
        topic = Topic(self.dp, topic_name, cls, qos=q)
        return DataWriter(self.pub, topic, qos=q)

    def reader(self, topic_name, cls, q):
        topic = Topic(self.dp, topic_name, cls, qos=q)
        return DataReader(self.sub, topic, qos=q)


def wait_matched(writer, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end and not pc.Stop.flag:
        if writer.get_publication_matched_status().current_count > 0:
            return True
        time.sleep(0.05)
    return False


def take_valid(reader):
    return [s for s in reader.take(N=256) if getattr(s, "sample_info", None) is not None
            and s.sample_info.valid_data]


# ---------------------------------------------------------------- commands


def cmd_publish_state(a) -> int:
    p = Peer(a.domain)
    ann_w = p.writer(pc.TOPIC_ANNOUNCEMENT, VehicleAnnouncement, QOS_ANNOUNCEMENT)
    ann_w.write(to_sample(VehicleAnnouncement, pc.announcement(a.vehicle_id, PEER)))
    pc.log(PEER, f"announced {a.vehicle_id}")
    w = p.writer(pc.TOPIC_STATE, StateVector, QOS_STATE)
    if not wait_matched(w, pc.MATCH_TIMEOUT_S):
        if pc.Stop.flag:
            return pc.Stop.code
        pc.log(PEER, f"no StateVector reader matched within {pc.MATCH_TIMEOUT_S:.0f} s")
        return 1
    pc.log(PEER, "StateVector reader matched")
    if not pc.sleep_unless_stopped(a.settle):
        return pc.Stop.code
    period = 1.0 / a.rate if a.rate > 0 else 0.0
    sent = 0
    for i in range(a.count):
        if pc.Stop.flag:
            break
        w.write(to_sample(StateVector, pc.state_vector(a.vehicle_id, i)))
        sent += 1
        if i + 1 < a.count and not pc.sleep_unless_stopped(period):
            break
    if not pc.Stop.flag:
        try:
            w.wait_for_acks(duration(seconds=a.linger))
        except Exception:  # noqa: BLE001 - best effort
            pass
        pc.sleep_unless_stopped(a.linger)
    pc.emit(f"published {sent}")
    return 0 if sent == a.count else pc.Stop.code


def cmd_publish_task(a) -> int:
    p = Peer(a.domain)
    w = p.writer(pc.TOPIC_TASK, TaskAssignment, QOS_TASK)
    if a.wait_match > 0 and not wait_matched(w, a.wait_match):
        pc.log(PEER, "no TaskAssignment reader matched yet; publishing anyway (transient-local)")
    w.write(to_sample(TaskAssignment, pc.goto_task(a.task_id, a.vehicle_id)))
    pc.log(PEER, f"published task {a.task_id} for {a.vehicle_id}; lingering {a.linger} s")
    pc.sleep_unless_stopped(a.linger)
    pc.emit("published 1")
    return 0


def cmd_subscribe_task(a) -> int:
    p = Peer(a.domain)
    r = p.reader(pc.TOPIC_TASK, TaskAssignment, QOS_TASK)
    got = 0
    end = time.monotonic() + a.timeout
    while got < a.expect:
        if pc.Stop.flag:
            return pc.Stop.code
        if time.monotonic() > end:
            pc.log(PEER, f"timeout: received {got} of {a.expect} TaskAssignments for {a.vehicle_id}")
            return 1
        for s in take_valid(r):
            if s.vehicle_id == a.vehicle_id and got < a.expect:
                pc.emit_json(to_dict(s))
                got += 1
        time.sleep(0.02)
    return 0


def cmd_subscribe_state(a) -> int:
    p = Peer(a.domain)
    r = p.reader(pc.TOPIC_STATE, StateVector, QOS_STATE)
    ra = p.reader(pc.TOPIC_ANNOUNCEMENT, VehicleAnnouncement, QOS_ANNOUNCEMENT) \
        if a.expect_announcements > 0 else None
    got = 0
    got_ann = 0
    end = time.monotonic() + a.timeout
    while got < a.expect or got_ann < a.expect_announcements:
        if pc.Stop.flag:
            return pc.Stop.code
        if time.monotonic() > end:
            pc.log(PEER, f"timeout: received {got} of {a.expect} StateVectors, "
                         f"{got_ann} of {a.expect_announcements} announcements")
            return 1
        if ra is not None:
            for s in take_valid(ra):
                if a.vehicle_id is None or s.vehicle_id == a.vehicle_id:
                    pc.emit("announcement " + json.dumps(to_dict(s), separators=(",", ":")))
                    got_ann += 1
        for s in take_valid(r):
            if (a.vehicle_id is None or s.vehicle_id == a.vehicle_id) and got < a.expect:
                pc.emit_json(to_dict(s))
                got += 1
        time.sleep(0.02)
    return 0


def _type(name: str):
    name = name.split("::")[-1]
    if name not in TYPES:
        raise SystemExit(f"unknown type {name}; one of {', '.join(TYPES)}")
    return TYPES[name]


def cmd_encode_sample(a) -> int:
    cls = _type(a.type)
    s = to_sample(cls, json.loads(a.json))
    data = s.serialize(use_version_2=False,
                       endianness=Endianness.Big if a.big_endian else Endianness.Little)
    if not a.header:
        data = data[4:]
    pc.emit(data.hex())
    return 0


def cmd_decode_sample(a) -> int:
    cls = _type(a.type)
    data = bytes.fromhex("".join(a.hex.split()))
    if a.header:
        s = cls.deserialize(data, has_header=True)
    else:
        s = cls.deserialize(b"\x00\x01\x00\x00" + data, has_header=True)
    pc.emit_json(to_dict(s))
    return 0


def cmd_key_hash(a) -> int:
    cls = _type(a.type)
    s = to_sample(cls, json.loads(a.json))
    # RTPS 9.6.3.8: big-endian plain CDR of the key members; MD5 unless the
    # maximum key size is <= 16 bytes (never the case for Shoal's string keys).
    key_be = s.serialize_key(endianness=Endianness.Big, use_version_2=False)[4:]
    idl = cls.__idl__
    if not idl._populated:
        idl.populate()
    if idl.v1_key_max_size <= 16:
        h = key_be.ljust(16, b"\x00")
    else:
        h = hashlib.md5(key_be).digest()
    pc.emit(h.hex())
    return 0


def extra(sub):
    s = sub.add_parser("encode-sample", help="print XCDR1 bytes of a sample as hex (no DDS)")
    s.add_argument("type")
    s.add_argument("json")
    s.add_argument("--header", action="store_true",
                   help="include the 4-byte encapsulation header (00 01 00 00 for CDR_LE)")
    s.add_argument("--big-endian", action="store_true", help="CDR_BE instead of CDR_LE")
    s = sub.add_parser("decode-sample", help="decode XCDR1 hex into JSON (no DDS)")
    s.add_argument("type")
    s.add_argument("hex")
    s.add_argument("--header", action="store_true",
                   help="hex starts with the 4-byte encapsulation header (else CDR_LE body)")
    s = sub.add_parser("key-hash", help="print the RTPS key hash (16 bytes hex) of a sample (no DDS)")
    s.add_argument("type")
    s.add_argument("json")


COMMANDS = {
    "publish-state": cmd_publish_state,
    "publish-task": cmd_publish_task,
    "subscribe-task": cmd_subscribe_task,
    "subscribe-state": cmd_subscribe_state,
    "encode-sample": cmd_encode_sample,
    "decode-sample": cmd_decode_sample,
    "key-hash": cmd_key_hash,
}


def main(argv=None) -> int:
    a = pc.parser("cyclone_peer.py", extra).parse_args(argv)
    pc.Stop.install()
    return COMMANDS[a.cmd](a)


if __name__ == "__main__":
    sys.exit(main())
