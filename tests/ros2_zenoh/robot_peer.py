#!/usr/bin/env python3
"""A ROS 2 robot on rmw_zenoh, played with PyPI eclipse-zenoh (no ROS installed), for
Shoal's ROS 2 proxy tests. Written from rmw_zenoh's design document (ros2/rmw_zenoh,
docs/design.md, rolling/Kilted) alone:

- topic key expressions <domain>/<fully qualified name, no leading slash>/<DDS type
  name>/<RIHS01 type hash> ("Topic and Service name mapping to Zenoh key expressions");
- liveliness tokens for its node (NN), publishers (MP) and subscription (MS):
  @ros2_lv/<domain>/<zid>/<node id>/<entity id>/<kind>/<enclave>/<namespace>/<node>
  [/<topic>/<type>/<hash>/<qos>], "/" mangled to "%" ("Graph Cache");
- payloads: CDR little endian with its 4-byte encapsulation header ("Serialization");
- each sample's attachment: sequence number (int64 LE), source timestamp (ns, int64 LE),
  GID length (1 byte, 16), GID (16 bytes) ("Publishers").

The type hashes are the ones rosidl generates for the message types (what a robot's
generated type support carries), not computed here.

It publishes sensor_msgs/NavSatFix (fix), nav_msgs/Odometry (odom) and
sensor_msgs/BatteryState (battery) at 10 Hz in --namespace, subscribes to
geometry_msgs/PoseStamped goals (goal_pose), and drives to each goal at --speed m/s in a
local ENU frame around --datum-lat/--datum-lon. It prints one JSON object per line:

    {"event": "ready", "zid": ...}                  tokens, publishers, subscriber declared
    {"event": "token", "kind": "NN"|"MP"|"MS"|..., "namespace": ..., "node": ...,
     "topic": ..., "type": ..., "hash_ok": bool, "qos": ...}   another session's entity
    {"event": "goal", "x": ..., "y": ..., "z": ..., "qx".."qw", "frame_id": ..., "sec": ...,
     "seq": ..., "gid": hex, "attachment_ok": bool, "why": ...}
    {"event": "garbage_sent"}                       with --garbage: the bad samples went out

With --garbage it also sends, once, fixes that a conforming subscriber must drop: one on a
key with another type hash, one whose CDR is truncated, one without an attachment, one
with a 5-byte attachment.

Network: it connects to --connect or listens on --listen (loopback endpoints in the
tests), never scouts by multicast, and has gossip off.
Runs until stdin closes or --lifetime seconds pass.
"""

import argparse
import json
import math
import os
import queue
import struct
import sys
import threading
import time

import zenoh

# RIHS01 hashes as rosidl generated them (ROS 2 Jazzy/Kilted message definitions).
HASHES = {
    "sensor_msgs::msg::dds_::NavSatFix_":
        "RIHS01_62223ab3fe210a15976021da7afddc9e200dc9ec75231c1b6a557fc598a65404",
    "nav_msgs::msg::dds_::Odometry_":
        "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "sensor_msgs::msg::dds_::BatteryState_":
        "RIHS01_4bee5dfce981c98faa6828b868307a0a73f992ed0789f374ee96c8f840e69741",
    "geometry_msgs::msg::dds_::PoseStamped_":
        "RIHS01_10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
    "rcl_interfaces::msg::dds_::Log_":
        "RIHS01_e28ce254ca8abc06abf92773b74602cdbf116ed34fbaf294fb9f81da9f318eac",
}
FIX_T = "sensor_msgs::msg::dds_::NavSatFix_"
ODOM_T = "nav_msgs::msg::dds_::Odometry_"
BATTERY_T = "sensor_msgs::msg::dds_::BatteryState_"
GOAL_T = "geometry_msgs::msg::dds_::PoseStamped_"
# ROS 2's default QoS (reliable, volatile, keep last 10) in rmw_zenoh's compact form.
QOS = "::,10:,:,:,,"

EARTH_A = 6378137.0
EARTH_E2 = 6.69437999014e-3


EMIT_LOCK = threading.Lock()


def emit(obj):
    # Zenoh's callback threads print too: one whole line at a time.
    line = json.dumps(obj) + "\n"
    with EMIT_LOCK:
        sys.stdout.write(line)
        sys.stdout.flush()


class Cdr:
    """Plain CDR, little endian; alignment counts from after the encapsulation header."""

    def __init__(self):
        self.body = bytearray()

    def align(self, n):
        while len(self.body) % n:
            self.body.append(0)

    def put(self, fmt, *values):
        self.align(struct.calcsize("<" + fmt.lstrip("0123456789")))
        self.body += struct.pack("<" + fmt, *values)

    def string(self, s):
        data = s.encode() + b"\0"
        self.put("I", len(data))
        self.body += data

    def header(self, stamp_ns, frame_id):
        self.put("i", stamp_ns // 1_000_000_000)
        self.put("I", stamp_ns % 1_000_000_000)
        self.string(frame_id)

    def bytes(self):
        return b"\x00\x01\x00\x00" + bytes(self.body)


class CdrReader:
    def __init__(self, data):
        if len(data) < 4 or data[0:2] != b"\x00\x01":
            raise ValueError("not CDR little endian")
        self.data, self.at = data[4:], 0

    def get(self, fmt):
        size = struct.calcsize("<" + fmt)
        while self.at % struct.calcsize("<" + fmt.lstrip("0123456789")):
            self.at += 1
        if self.at + size > len(self.data):
            raise ValueError("truncated")
        v = struct.unpack_from("<" + fmt, self.data, self.at)
        self.at += size
        return v

    def string(self):
        (n,) = self.get("I")
        if n == 0 or self.at + n > len(self.data) or self.data[self.at + n - 1] != 0:
            raise ValueError("bad string")
        s = self.data[self.at:self.at + n - 1].decode()
        self.at += n
        return s


def radii(lat_deg):
    s = math.sin(math.radians(lat_deg))
    w = 1.0 - EARTH_E2 * s * s
    return EARTH_A * (1.0 - EARTH_E2) / (w * math.sqrt(w)), EARTH_A / math.sqrt(w)


def to_geo(lat0, lon0, east, north):
    m, n = radii(lat0)
    return (lat0 + math.degrees(north / m),
            lon0 + math.degrees(east / (n * math.cos(math.radians(lat0)))))


class Publisher:
    """One rmw_zenoh publisher: its key, sequence numbers and GID."""

    def __init__(self, session, domain, fq_topic, dds_type):
        self.key = f"{domain}/{fq_topic.strip('/')}/{dds_type}/{HASHES[dds_type]}"
        self.pub = session.declare_publisher(self.key)
        self.seq = 0
        self.gid = os.urandom(16)

    def attachment(self):
        self.seq += 1
        return struct.pack("<qqB", self.seq, time.time_ns(), 16) + self.gid

    def put(self, payload):
        self.pub.put(payload, attachment=self.attachment())


def mangle(name):
    return name.replace("/", "%") if name else "%"


def token(domain, zid, node_id, entity_id, kind, ns, node, topic=None):
    key = f"@ros2_lv/{domain}/{zid}/{node_id}/{entity_id}/{kind}/%/{mangle(ns)}/{node}"
    if topic:
        fq, dds_type = topic
        key += f"/{mangle(fq)}/{dds_type}/{HASHES[dds_type]}/{QOS}"
    return key


def check_attachment(att, last_seq):
    """Why an attachment is not the design document's, or None."""
    if att is None:
        return "no attachment"
    if len(att) != 33:
        return f"{len(att)} bytes"
    seq, ts, gid_len = struct.unpack_from("<qqB", att)
    if gid_len != 16:
        return f"GID length {gid_len}"
    if seq <= last_seq:
        return f"sequence {seq} after {last_seq}"
    if abs(ts - time.time_ns()) > 60 * 1_000_000_000:
        return f"timestamp {ts} is not now"
    return None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect")
    ap.add_argument("--listen")
    ap.add_argument("--domain", type=int, default=0)
    ap.add_argument("--namespace", default="auv1")
    ap.add_argument("--node", default="autopilot")
    ap.add_argument("--datum-lat", type=float, default=59.9)
    ap.add_argument("--datum-lon", type=float, default=10.7)
    ap.add_argument("--east", type=float, default=10.0)
    ap.add_argument("--north", type=float, default=-20.0)
    ap.add_argument("--depth", type=float, default=2.5)
    ap.add_argument("--battery", type=float, default=0.64)
    ap.add_argument("--speed", type=float, default=20.0)
    ap.add_argument("--garbage", action="store_true")
    ap.add_argument("--lifetime", type=float, default=300.0)
    args = ap.parse_args()

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([args.connect] if args.connect else []))
    conf.insert_json5("listen/endpoints", json.dumps([args.listen] if args.listen else []))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    session = zenoh.open(conf)
    zid = str(session.zid())
    d, ns = args.domain, "/" + args.namespace.strip("/")
    fq = lambda name: f"{ns}/{name}"

    # Graph: what other sessions declare.
    def on_token(sample):
        key = str(sample.key_expr)
        parts = key.split("/")
        if sample.kind != zenoh.SampleKind.PUT or len(parts) not in (9, 13) or parts[2] == zid:
            return
        ev = {"event": "token", "kind": parts[5], "namespace": parts[7].replace("%", "/"),
              "node": parts[8], "key": key}
        if len(parts) == 13:
            ev.update(topic=parts[9].replace("%", "/"), type=parts[10],
                      hash_ok=HASHES.get(parts[10]) == parts[11], qos=parts[12])
        emit(ev)

    graph = session.liveliness().declare_subscriber(f"@ros2_lv/{d}/**", on_token, history=True)

    goals = queue.Queue()
    last_goal_seq = [0]

    def on_goal(sample):
        att = sample.attachment.to_bytes() if sample.attachment is not None else None
        why = check_attachment(att, last_goal_seq[0])
        ev = {"event": "goal", "key": str(sample.key_expr), "attachment_ok": why is None,
              "why": why}
        if att is not None and len(att) == 33:
            seq, _, _ = struct.unpack_from("<qqB", att)
            last_goal_seq[0] = max(last_goal_seq[0], seq)
            ev.update(seq=seq, gid=att[17:].hex())
        try:
            r = CdrReader(sample.payload.to_bytes())
            (sec,) = r.get("i")
            r.get("I")
            frame_id = r.string()
            x, y, z, qx, qy, qz, qw = r.get("7d")
            ev.update(x=x, y=y, z=z, qx=qx, qy=qy, qz=qz, qw=qw, frame_id=frame_id, sec=sec)
            goals.put((x, y, -z))
        except (ValueError, UnicodeDecodeError) as e:
            ev.update(decode_error=str(e))
        emit(ev)

    goal_key = f"{d}/{fq('goal_pose').strip('/')}/{GOAL_T}/{HASHES[GOAL_T]}"
    goal_sub = session.declare_subscriber(goal_key, on_goal)

    fix_pub = Publisher(session, d, fq("fix"), FIX_T)
    odom_pub = Publisher(session, d, fq("odom"), ODOM_T)
    bat_pub = Publisher(session, d, fq("battery"), BATTERY_T)
    tokens = [session.liveliness().declare_token(k) for k in [
        token(d, zid, 0, 0, "NN", ns, args.node),
        token(d, zid, 0, 10, "MP", ns, args.node, (fq("fix"), FIX_T)),
        token(d, zid, 0, 11, "MP", ns, args.node, (fq("odom"), ODOM_T)),
        token(d, zid, 0, 12, "MP", ns, args.node, (fq("battery"), BATTERY_T)),
        token(d, zid, 0, 13, "MS", ns, args.node, (fq("goal_pose"), GOAL_T)),
    ]]
    emit({"event": "ready", "zid": zid})

    stop = threading.Event()

    def watch_stdin():
        sys.stdin.read()
        stop.set()

    threading.Thread(target=watch_stdin, daemon=True).start()

    x, y, depth = args.east, args.north, args.depth
    target = None
    heading = 0.0  # ENU yaw, rad: 0 faces east
    garbage_due = args.garbage
    deadline = time.time() + args.lifetime
    while not stop.is_set() and time.time() < deadline:
        try:
            while True:
                target = goals.get_nowait()
        except queue.Empty:
            pass
        if target is not None:
            tx, ty, tdepth = target
            dx, dy = tx - x, ty - y
            dist = math.hypot(dx, dy)
            step = args.speed * 0.1
            if dist > step:
                heading = math.atan2(dy, dx)
                x, y = x + dx / dist * step, y + dy / dist * step
            else:
                x, y = tx, ty
            depth += max(-step, min(step, tdepth - depth))
        now = time.time_ns()
        lat, lon = to_geo(args.datum_lat, args.datum_lon, x, y)

        fix = Cdr()
        fix.header(now, "gps")
        fix.put("b", 0)
        fix.put("H", 1)
        fix.put("3d", lat, lon, 0.0)
        fix.put("9d", *([0.0] * 9))
        fix.put("B", 0)
        fix_pub.put(fix.bytes())

        odom = Cdr()
        odom.header(now, "odom")
        odom.string("base_link")
        odom.put("7d", x, y, -depth, 0.0, 0.0, math.sin(heading / 2), math.cos(heading / 2))
        odom.put("36d", *([0.0] * 36))
        odom.put("6d", 1.0 if target is not None else 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        odom.put("36d", *([0.0] * 36))
        odom_pub.put(odom.bytes())

        bat = Cdr()
        bat.header(now, "battery")
        bat.put("7f", 15.2, 20.0, -3.0, 10.0, 16.0, 16.0, args.battery)
        bat.put("3B", 2, 1, 3)
        bat.put("?", True)
        bat.put("I", 0)
        bat.put("I", 0)
        bat.string("hull")
        bat.string("SN-1")
        bat_pub.put(bat.bytes())

        if garbage_due:
            garbage_due = False
            wrong = f"{d}/{fq('fix').strip('/')}/{FIX_T}/RIHS01_" + "0" * 64
            session.put(wrong, fix.bytes(), attachment=fix_pub.attachment())
            fix_pub.pub.put(fix.bytes()[:20], attachment=fix_pub.attachment())
            fix_pub.pub.put(fix.bytes())
            fix_pub.pub.put(fix.bytes(), attachment=b"\x01\x02\x03\x04\x05")
            emit({"event": "garbage_sent"})
        time.sleep(0.1)

    for t in tokens:
        t.undeclare()
    goal_sub.undeclare()
    graph.undeclare()
    session.close()


if __name__ == "__main__":
    main()
