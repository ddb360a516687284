#!/usr/bin/env python3
"""An independent shore-side client of Shoal's federation, written from docs/federation.md
alone (key expressions, wire version 1, catch-up queries), with PyPI eclipse-zenoh.

It connects to one endpoint (never scouts), subscribes to every site's positions, alarms,
task transitions and environment summaries, asks the site named by --site for the alarms and transitions it
already published (the catch-up queryable), decodes each payload, and prints one JSON
object per line on stdout:

    {"event": "ready"}                                  subscribers declared
    {"event": "position", "site": ..., "vehicle": ..., ...}
    {"event": "alarm", "site": ..., "epoch": ..., "seq": ..., ...}
    {"event": "task", "site": ..., "epoch": ..., "seq": ..., ...}
    {"event": "environment", "site": ..., "vehicle": ..., "properties": [...], ...}
    {"event": "catchup_end", "site": ..., "stream": ..., "epoch": ..., "oldest": ...,
     "highest": ...}                                    the last reply of a catch-up answer
    {"event": "refused", "key": ..., "reason": ...}     a payload that does not decode

Alarms, transitions and environment frames are printed once per (site, epoch, seq),
however often they arrive. It exits 0 once it has printed at least --positions
positions, --alarms alarms, --tasks transitions and --environment environment frames,
or 1 after --timeout seconds.

Usage: shore_client.py --connect tcp/127.0.0.1:7447 --site ship [--positions 1]
       [--alarms 1] [--tasks 1] [--environment 0] [--timeout 30]
"""

import argparse
import json
import queue
import struct
import sys
import time

import zenoh

WIRE_VERSION = 1
KIND_POSITION, KIND_ALARM, KIND_TASK, KIND_ENVIRONMENT, KIND_CATCHUP_END = 1, 2, 3, 6, 8

# Code tables ("Codes" in docs/federation.md).
VEHICLE_KINDS = ["auv", "usv", "asv", "rov", "glider"]
SEVERITIES = ["info", "warning", "alarm", "critical"]
EVENT_KINDS = ["low_battery", "out_of_area", "comm_lost", "fault", "detection", "task",
               "rule", "data_rejected", "other"]
TASK_STATES = ["pending", "sent", "accepted", "running", "done", "failed", "aborted",
               "expired"]


class Refused(Exception):
    """A payload that is not a valid version-1 frame."""


class Reader:
    """Reads little-endian fields from a frame, refusing to read past its end."""

    def __init__(self, data: bytes):
        self.data, self.at = data, 0

    def take(self, n: int, field: str) -> bytes:
        if self.at + n > len(self.data):
            raise Refused(f"truncated at {field}")
        chunk = self.data[self.at:self.at + n]
        self.at += n
        return chunk

    def u8(self, field):
        return self.take(1, field)[0]

    def u16(self, field):
        return struct.unpack("<H", self.take(2, field))[0]

    def i32(self, field):
        return struct.unpack("<i", self.take(4, field))[0]

    def u64(self, field):
        return struct.unpack("<Q", self.take(8, field))[0]

    def u48(self, field):
        return int.from_bytes(self.take(6, field), "little")

    def str8(self, field):
        return self.take(self.u8(field), field).decode("utf-8")

    def code(self, table, field):
        value = self.u8(field)
        if value >= len(table):
            raise Refused(f"unknown {field} code {value}")
        return table[value]

    def header(self, kind):
        version, found = self.u8("version"), self.u8("kind")
        if version != WIRE_VERSION:
            raise Refused(f"wire version {version}")
        if found != kind:
            raise Refused(f"kind {found}, expected {kind}")

    def end(self):
        if self.at != len(self.data):
            raise Refused(f"{len(self.data) - self.at} bytes after the end")


def decode_position(site, vehicle, data):
    """Position frame: 24 bytes, fixed point ("Position frame" table)."""
    r = Reader(data)
    r.header(KIND_POSITION)
    out = {
        "event": "position", "site": site, "vehicle": vehicle,
        "kind": r.code(VEHICLE_KINDS, "vehicle_kind"),
        "timestamp_ms": r.u48("timestamp_ms"),
        "latitude_deg": r.i32("latitude") * 1e-7,
        "longitude_deg": r.i32("longitude") * 1e-7,
        "depth_m": r.u16("depth") * 0.2,
        "heading_deg": r.u16("heading") * 360.0 / 65536.0,
        "speed_mps": r.u16("speed") * 0.01,
        "battery_pct": r.u8("battery") * 0.5,
    }
    r.end()
    if abs(out["latitude_deg"]) > 90 or abs(out["longitude_deg"]) > 180:
        raise Refused("position out of range")
    return out


def envelope(r, kind):
    """Header of an alarm or task frame: site, epoch, sequence number, timestamp."""
    r.header(kind)
    return {"site": r.str8("site"), "epoch": r.u64("epoch"), "seq": r.u64("seq"),
            "timestamp_ms": r.u48("timestamp_ms")}


def decode_alarm(data):
    r = Reader(data)
    out = {"event": "alarm", **envelope(r, KIND_ALARM)}
    out["severity"] = r.code(SEVERITIES, "severity")
    out["event_kind"] = r.code(EVENT_KINDS, "event_kind")
    out["event_id"] = r.str8("event_id")
    out["vehicle_id"] = r.str8("vehicle_id")
    out["task_id"] = r.str8("task_id")
    out["text"] = r.take(r.u16("text"), "text").decode("utf-8")
    r.end()
    return out


def decode_task(data):
    r = Reader(data)
    out = {"event": "task", **envelope(r, KIND_TASK)}
    out["state"] = r.code(TASK_STATES, "state")
    out["task_id"] = r.str8("task_id")
    out["mission_id"] = r.str8("mission_id")
    out["vehicle_id"] = r.str8("vehicle_id")
    r.end()
    return out


def decode_environment(site, vehicle, data):
    """Environment frame: a vehicle's summaries of one window ("Environment frame")."""
    r = Reader(data)
    out = {"event": "environment", **envelope(r, KIND_ENVIRONMENT), "vehicle": vehicle}
    # The envelope's timestamp is the window's end.
    out["window_end_ms"] = out.pop("timestamp_ms")
    out["window_start_ms"] = r.u48("window_start")
    if not out["window_start_ms"] < out["window_end_ms"] <= out["window_start_ms"] + 3_600_000:
        raise Refused("window")
    n = r.u8("count")
    if not 1 <= n <= 32:
        raise Refused("property count")
    props = []
    for _ in range(n):
        p = {"property": r.str8("property"), "unit": r.str8("unit"),
             "count": struct.unpack("<I", r.take(4, "count"))[0]}
        for field in ("min", "max", "mean", "last_value"):
            p[field] = struct.unpack("<d", r.take(8, field))[0]
        p["last_ms"] = r.u48("last_time")
        p["latitude_deg"] = r.i32("latitude") * 1e-7
        p["longitude_deg"] = r.i32("longitude") * 1e-7
        p["depth_m"] = r.u16("depth") * 0.2
        if p["count"] < 1 or not p["min"] <= p["mean"] <= p["max"] \
                or not p["min"] <= p["last_value"] <= p["max"]:
            raise Refused(f"summary of {p['property']}")
        props.append(p)
    if len({p["property"] for p in props}) != n:
        raise Refused("a property twice")
    out["properties"] = props
    r.end()
    return out


def decode_catchup_end(stream, data):
    r = Reader(data)
    r.header(KIND_CATCHUP_END)
    out = {"event": "catchup_end", "site": r.str8("site"), "stream": stream,
           "epoch": r.u64("epoch"), "oldest": r.u64("oldest"), "highest": r.u64("highest")}
    r.end()
    return out


def decode(key: str, data: bytes):
    """Dispatches on the key expression ("Key expressions" in the doc)."""
    chunks = key.split("/")
    if len(chunks) < 3 or chunks[0] != "shoal":
        raise Refused("not a federation key")
    site = chunks[1]
    rest = chunks[2:]
    if len(rest) == 3 and rest[0] == "vehicles" and rest[2] == "position":
        return decode_position(site, rest[1], data)
    if len(rest) == 2 and rest[0] == "environment":
        item = decode_environment(site, rest[1], data)
    elif len(rest) == 2 and rest[0] == "catchup" and data[1:2] == bytes([KIND_CATCHUP_END]):
        item = decode_catchup_end(rest[1], data)
    elif rest in (["alarms"], ["catchup", "alarms"]):
        item = decode_alarm(data)
    elif (len(rest) == 2 and rest[0] == "tasks") or rest == ["catchup", "tasks"]:
        item = decode_task(data)
    else:
        raise Refused("not a federation key")
    if item["site"] != site:
        raise Refused("site in frame differs from site in key")
    return item


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True)
    ap.add_argument("--site", required=True)
    ap.add_argument("--positions", type=int, default=1)
    ap.add_argument("--alarms", type=int, default=1)
    ap.add_argument("--tasks", type=int, default=1)
    ap.add_argument("--environment", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=30.0)
    args = ap.parse_args()

    conf = zenoh.Config()
    # The doc's network rule: connect only where told, never scout.
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("connect/endpoints", json.dumps([args.connect]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    session = zenoh.open(conf)

    inbox = queue.Queue()

    def on_sample(sample):
        inbox.put((str(sample.key_expr), sample.payload.to_bytes()))

    subscribers = [session.declare_subscriber(k, on_sample)
                   for k in ("shoal/*/vehicles/*/position", "shoal/*/alarms",
                             "shoal/*/tasks/*", "shoal/*/environment/*")]
    print(json.dumps({"event": "ready"}), flush=True)

    # What the site published before we came: its catch-up queryables, all replies kept
    # (they share one key, so consolidation must be off).
    for stream in ("alarms", "tasks"):
        replies = session.get(f"shoal/{args.site}/catchup/{stream}?after=0",
                              consolidation=zenoh.ConsolidationMode.NONE, timeout=10)
        for reply in replies:
            if reply.ok is not None:
                inbox.put((str(reply.ok.key_expr), reply.ok.payload.to_bytes()))

    seen = set()
    counts = {"position": 0, "alarm": 0, "task": 0, "environment": 0}
    wanted = {"position": args.positions, "alarm": args.alarms, "task": args.tasks,
              "environment": args.environment}
    deadline = time.monotonic() + args.timeout
    while any(counts[k] < wanted[k] for k in counts):
        left = deadline - time.monotonic()
        if left <= 0:
            print(json.dumps({"event": "timeout", "counts": counts}), flush=True)
            sys.exit(1)
        try:
            key, data = inbox.get(timeout=left)
        except queue.Empty:
            continue
        try:
            item = decode(key, data)
        except (Refused, UnicodeDecodeError) as e:
            print(json.dumps({"event": "refused", "key": key, "reason": str(e)}), flush=True)
            continue
        if item["event"] == "catchup_end":
            print(json.dumps(item), flush=True)
            continue
        if item["event"] != "position":
            ident = (item["site"], item["event"], item["epoch"], item["seq"])
            if ident in seen:
                continue
            seen.add(ident)
        counts[item["event"]] += 1
        print(json.dumps(item), flush=True)

    for s in subscribers:
        s.undeclare()
    session.close()


if __name__ == "__main__":
    main()
