#!/usr/bin/env python3
"""Packet-level half of the attack corpus (tests/security/attack_corpus.sh): captures the
real, secured RTPS traffic of a legitimate vehicle on `lo` (AF_PACKET, root, inside the
test's network namespace) and injects mutated copies of it through plain UDP sockets into
the station's RTPS locators. Python 3 standard library only.

  attack_corpus.py packets --vehicle ID --api URL --token T --work DIR [--scale F]

Protocol with the shell script (files in DIR):
  sniff.ready     written once the capture runs
  run1.done       the script writes it when the vehicle's first session (the "old"
                  session, replayed later) has ended
  attacking       written when the injection starts (the script then starts its
                  credential attacks) ...
  packets.json    ... and the result, when it ends: cases and station counters by kind

Kinds (each case is one datagram sent to a station locator):
  replay-live        exact copies of the vehicle's current session, seconds later
  replay-old         exact copies of the vehicle's previous session (participant gone)
  flip-header        one bit flipped in the RTPS header (protocol, version, vendor, GUID prefix)
  flip-submsg-header one bit flipped in a submessage header (id, flags, length)
  flip-sec-prefix    one bit flipped in SEC_PREFIX (transformation kind, key id, session, IV)
  flip-ciphertext    one bit flipped in SEC_BODY (length or ciphertext)
  flip-mac           one bit flipped in SEC_POSTFIX (common or receiver-specific MAC)
  flip-clear         one bit flipped in a clear submessage (INFO_TS, INFO_DST, SPDP,
                     handshake, ...) of the vehicle's traffic
  truncated          cut anywhere after the RTPS header (in particular inside SEC_* parts)
  extended           random bytes or a bogus submessage appended, or a length field grown
  readdressed        the GUID prefix replaced (random, the station's own, a neighbour's)
  forged-packet      built from scratch as the vehicle: clear DATA with a StateVector for
                     it (its writer ids guessed), clear HEARTBEAT/GAP that would skip its
                     samples, SEC_* with random ciphertext, SPDP dispose of its participant
"""

import argparse
import json
import os
import random
import socket
import struct
import sys
import threading
import time
import urllib.request

ETH_P_ALL = 0x0003
SEC_BODY, SEC_PREFIX, SEC_POSTFIX, SRTPS_PREFIX, SRTPS_POSTFIX = 0x30, 0x31, 0x32, 0x33, 0x34
DATA, DATA_FRAG, HEARTBEAT, ACKNACK, GAP, INFO_TS, INFO_DST = 0x15, 0x16, 0x07, 0x06, 0x08, 0x09, 0x0E
SEC_IDS = (SEC_BODY, SEC_PREFIX, SEC_POSTFIX, SRTPS_PREFIX, SRTPS_POSTFIX)
SPDP_WRITER = bytes.fromhex("000100c2")
SPDP_READER = bytes.fromhex("000100c7")

KINDS = [
    "replay-live", "replay-old", "flip-header", "flip-submsg-header", "flip-sec-prefix",
    "flip-ciphertext", "flip-mac", "flip-clear", "truncated", "extended", "readdressed",
    "forged",
]


def log(*a):
    print("attack_corpus.py:", *a, file=sys.stderr, flush=True)


# ------------------------------------------------------------------ RTPS parsing

def submessages(d):
    """[(id, flags, start, body_start, end)] of an RTPS datagram (best effort)."""
    out, i = [], 20
    while i + 4 <= len(d):
        sid, fl = d[i], d[i + 1]
        n = struct.unpack_from("<H" if fl & 1 else ">H", d, i + 2)[0]
        end = len(d) if n == 0 and sid not in (0x0C, 0x01) else i + 4 + n  # 0: to the end
        if end > len(d):
            break
        out.append((sid, fl, i, i + 4, end))
        i = end
    return out


def parameters(pl, little=True):
    """{pid: [value bytes]} of a ParameterList (after the 4-byte encapsulation)."""
    e = "<" if little else ">"
    out, i = {}, 0
    while i + 4 <= len(pl):
        pid, n = struct.unpack_from(e + "HH", pl, i)
        if pid == 1:  # PID_SENTINEL
            break
        out.setdefault(pid & 0x3FFF, []).append(pl[i + 4:i + 4 + n])
        i += 4 + n
    return out


def spdp_data(d):
    """(guid prefix, parameters) of a clear SPDP DATA in datagram d, or None."""
    for sid, fl, s, b, e in submessages(d):
        if sid != DATA or d[b + 8:b + 12] != SPDP_WRITER:
            continue
        little = bool(fl & 1)
        octets_to_inline = struct.unpack_from("<H" if little else ">H", d, b + 2)[0]
        p = b + 4 + octets_to_inline
        if fl & 0x02:  # inline QoS
            while p + 4 <= e:
                pid, n = struct.unpack_from("<HH" if little else ">HH", d, p)
                p += 4 + n
                if pid == 1:
                    break
        payload = d[p:e]
        if len(payload) < 4:
            continue
        enc = payload[:2]
        params = parameters(payload[4:], little=enc in (b"\x00\x03", b"\x00\x01"))
        return d[8:20], params
    return None


def locators(params):
    """Unicast UDPv4 (ip, port) locators of a participant's SPDP parameters."""
    out = set()
    for pid in (0x0031, 0x0032):  # default / metatraffic unicast
        for v in params.get(pid, []):
            if len(v) < 24:
                continue
            kind, port = struct.unpack_from("<iI", v, 0)
            if kind == 1:
                out.add((socket.inet_ntoa(v[20:24]), port))
    return out


# ------------------------------------------------------------------ who is who

def _tlv(b, i):  # (tag, start of value, end of value) of the DER element at i
    tag, n = b[i], b[i + 1]
    i += 2
    if n & 0x80:
        k = n & 0x7F
        n = int.from_bytes(b[i:i + k], "big")
        i += k
    return tag, i, i + n


def guid_head(cert_pem_path):
    """The first 6 bytes of the GUID prefix of a participant with this certificate: DDS
    Security 1.1 9.3.3 sets them to a 1 bit then the first 47 bits of SHA-256 of the
    certificate's DER subject (the identity token in SPDP does not carry the subject)."""
    import base64
    import hashlib
    pem = open(cert_pem_path).read()
    der = base64.b64decode("".join(l for l in pem.splitlines() if l and not l.startswith("-----")))
    _, cs, _ = _tlv(der, 0)
    _, ts, te = _tlv(der, cs)
    i, fields = ts, []
    while i < te:
        tag, vs, ve = _tlv(der, i)
        fields.append((tag, i, ve))
        i = ve
    if fields[0][0] == 0xA0:
        fields = fields[1:]
    _, s, e = fields[4]
    h = int.from_bytes(hashlib.sha256(der[s:e]).digest()[:6], "big")
    return ((h >> 1) | (1 << 47)).to_bytes(6, "big")


# ------------------------------------------------------------------ capture

class Capture(threading.Thread):
    """Every RTPS datagram on lo, with what the station and the vehicle are."""

    def __init__(self, vehicle_cert, station_cert):
        super().__init__(daemon=True)
        self.vehicle = guid_head(vehicle_cert)
        self.station = guid_head(station_cert)
        log(f"GUID prefixes from the certificates: vehicle {self.vehicle.hex()}.., station {self.station.hex()}..")
        self.lock = threading.Lock()
        self.sessions = []           # guid prefixes of the vehicle, in order seen
        self.station_prefix = None
        self.station_locs = set()
        self.others = set()          # other participants' prefixes
        self.by_prefix = {}          # prefix -> [(dst, datagram)]
        self.sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
        self.sock.bind(("lo", 0))
        self.sock.settimeout(0.2)
        self.stop = False
        self.own_ports = set()

    def run(self):
        while not self.stop:
            try:
                frame, addr = self.sock.recvfrom(65535)
            except (socket.timeout, InterruptedError):
                continue
            if addr[2] == socket.PACKET_OUTGOING:  # lo shows each datagram twice
                continue
            ip = frame[14:]
            if len(ip) < 28 or ip[0] >> 4 != 4 or ip[9] != 17:
                continue
            ihl = (ip[0] & 15) * 4
            sport, dport = struct.unpack_from(">HH", ip, ihl)
            d = ip[ihl + 8:]
            if d[:4] != b"RTPS" or len(d) < 20 or sport in self.own_ports:
                continue
            dst = (socket.inet_ntoa(ip[16:20]), dport)
            prefix = d[8:20]
            sp = spdp_data(d)
            with self.lock:
                if sp is not None:
                    p, params = sp
                    if p[:6] == self.vehicle and p not in self.sessions:
                        self.sessions.append(p)
                        log(f"vehicle session {len(self.sessions)}: guid prefix {p.hex()}")
                    elif p[:6] == self.station and self.station_prefix is None:
                        self.station_prefix = p
                        self.station_locs = locators(params)
                        log(f"station: guid prefix {p.hex()}, locators {sorted(self.station_locs)}")
                    elif p not in self.sessions and p != self.station_prefix and p not in self.others:
                        self.others.add(p)
                        log(f"other participant: guid prefix {p.hex()}, {len(params)} parameters")
                self.by_prefix.setdefault(prefix, []).append((dst, bytes(d)))

    def packets(self, prefix):
        with self.lock:
            return list(self.by_prefix.get(prefix, []))


# ------------------------------------------------------------------ mutations

def flip(d, lo, hi, rng):
    if hi <= lo:
        return None
    b = bytearray(d)
    i = rng.randrange(lo, hi)
    b[i] ^= 1 << rng.randrange(8)
    return bytes(b)


def regions(d):
    """Byte ranges of a datagram by part, for the flips."""
    r = {"flip-header": [(0, 20)], "flip-submsg-header": [], "flip-sec-prefix": [],
         "flip-ciphertext": [], "flip-mac": [], "flip-clear": []}
    for sid, fl, s, b, e in submessages(d):
        r["flip-submsg-header"].append((s, b))
        if sid in (SEC_PREFIX, SRTPS_PREFIX):
            r["flip-sec-prefix"].append((b, e))
        elif sid == SEC_BODY:
            r["flip-ciphertext"].append((b, e))
        elif sid in (SEC_POSTFIX, SRTPS_POSTFIX):
            r["flip-mac"].append((b, e))
        elif e > b:
            r["flip-clear"].append((b, e))
    return r


def pick_flip(kind, d, rng):
    rs = [x for x in regions(d)[kind] if x[1] > x[0]]
    if not rs:
        return None
    lo, hi = rng.choice(rs)
    return flip(d, lo, hi, rng)


def truncate(d, rng):
    subs = submessages(d)
    secs = [(b, e) for sid, _, _, b, e in subs if sid in SEC_IDS and e > b]
    if secs and rng.random() < 0.6:
        b, e = rng.choice(secs)
        cut = rng.randrange(b, e)
    else:
        cut = rng.randrange(20, len(d)) if len(d) > 20 else 10
    return d[:cut]


def extend(d, rng):
    choice = rng.randrange(3)
    if choice == 0:
        return d + rng.randbytes(rng.randrange(1, 65))
    if choice == 1:  # a bogus submessage (random id among the security ones, random body)
        body = rng.randbytes(rng.choice((4, 16, 20, 36, 60)))
        return d + bytes([rng.choice(SEC_IDS + (DATA, HEARTBEAT, GAP)), 0x01]) + struct.pack("<H", len(body)) + body
    subs = submessages(d)
    if not subs:
        return d + b"\0" * 8
    sid, fl, s, b, e = rng.choice(subs)
    n = struct.unpack_from("<H" if fl & 1 else ">H", d, s + 2)[0]
    grow = rng.choice((4, 8, 64, 1000))
    out = bytearray(d) + rng.randbytes(grow)
    struct.pack_into("<H" if fl & 1 else ">H", out, s + 2, min(n + grow, 0xFFFF))
    return bytes(out)


def readdress(d, rng, prefixes):
    b = bytearray(d)
    if prefixes and rng.random() < 0.5:
        b[8:20] = rng.choice(prefixes)
    else:
        b[8:20] = rng.randbytes(12)
    return bytes(b)


def header(prefix):
    return b"RTPS" + bytes([2, 3, 0x01, 0x10]) + prefix


def sub(sid, body, flags=0x01):
    return bytes([sid, flags]) + struct.pack("<H", len(body)) + body


def seq(n):
    return struct.pack("<iI", n >> 32, n & 0xFFFFFFFF)


def forged_cases(prefix, station_prefix, state_cdr, rng, n):
    """n datagrams forged as the vehicle's participant."""
    # Cyclone numbers entities per participant: <counter:3 bytes><kind>; 0x02/0x03 =
    # user writer with/without key. Guess the first 24 counters of both kinds.
    writers = [struct.pack(">I", (c << 8) | k) for c in range(1, 25) for k in (0x02, 0x03)]
    out = []
    info_dst = sub(INFO_DST, station_prefix)
    info_ts = sub(INFO_TS, struct.pack("<iI", int(time.time()), 0))
    spdp_dispose = None
    for i in range(n):
        w = writers[i % len(writers)]
        t = i % 8
        if t == 0:    # clear DATA with a StateVector for the vehicle, far ahead in sequence
            body = struct.pack("<HH", 0, 16) + b"\0\0\0\0" + w + seq(1000 + i) + state_cdr
            m = info_ts + sub(DATA, body, 0x05)
        elif t == 1:  # same, sequence number 1 (what a fresh writer starts with)
            body = struct.pack("<HH", 0, 16) + b"\0\0\0\0" + w + seq(1) + state_cdr
            m = info_dst + info_ts + sub(DATA, body, 0x05)
        elif t == 2:  # HEARTBEAT that says samples 1..10^6 are gone: a reader would skip them
            body = b"\0\0\0\0" + w + seq(1_000_000) + seq(1_000_010) + struct.pack("<I", i)
            m = info_dst + sub(HEARTBEAT, body, 0x03)
        elif t == 3:  # GAP that declares samples 1..10^6 irrelevant
            body = b"\0\0\0\0" + w + seq(1) + seq(1_000_000) + struct.pack("<I", 0)
            m = info_dst + sub(GAP, body)
        elif t == 4:  # SEC_PREFIX/BODY/POSTFIX with random key id, session, IV, ciphertext, MAC
            pre = bytes([0, 0, 1, 2]) + rng.randbytes(16)
            ct = rng.randbytes(rng.choice((32, 64, 120)))
            m = sub(SEC_PREFIX, pre) + sub(SEC_BODY, struct.pack(">I", len(ct)) + ct) + \
                sub(SEC_POSTFIX, rng.randbytes(16) + struct.pack(">I", 0))
        elif t == 5:  # clear DATA on the secure builtin writers (SEDP, participant messages)
            bw = rng.choice([bytes.fromhex(x) for x in ("ff0003c2", "ff0004c2", "ff0200c2", "ff0202c3", "000003c2", "000004c2")])
            body = struct.pack("<HH", 0, 16) + b"\0\0\0\0" + bw + seq(500 + i) + state_cdr
            m = info_ts + sub(DATA, body, 0x05)
        elif t == 6:  # SPDP "participant disposed" for the vehicle (PID_STATUS_INFO = 3)
            if spdp_dispose is None:
                pl = struct.pack("<HH", 0x0070, 16) + prefix + bytes.fromhex("000001c1")
                pl += struct.pack("<HH", 0x0071, 4) + bytes([0, 0, 0, 3]) + struct.pack("<HH", 1, 0)
                inline = pl
                body = struct.pack("<HH", 0, 16) + SPDP_READER + SPDP_WRITER + seq(10_000) + inline
                spdp_dispose = sub(DATA, body, 0x03)
            m = info_ts + spdp_dispose
        else:         # ACKNACK and random submessages
            body = b"\0\0\0\0" + w + seq(1) + struct.pack("<I", 0) + struct.pack("<I", i)
            m = info_dst + sub(ACKNACK, body, 0x03) + sub(rng.randrange(0x40, 0x80), rng.randbytes(12))
        out.append(header(prefix) + m)
    return out


# ------------------------------------------------------------------ the station's view

class Api:
    def __init__(self, base, token):
        self.base, self.token = base.rstrip("/"), token

    def get(self, path):
        req = urllib.request.Request(self.base + path, headers={"Authorization": f"Bearer {self.token}"})
        with urllib.request.urlopen(req, timeout=10) as r:
            return json.load(r)

    def snapshot(self):
        try:
            stats = self.get("/api/stats")
            fleet = self.get("/api/fleet")
        except Exception as e:  # noqa: BLE001 (a failed read is reported, not fatal)
            return {"error": repr(e)}
        ing = stats.get("ingest", stats)
        items = fleet.get("vehicles", fleet) if isinstance(fleet, dict) else fleet
        vehicles = {}
        for v in items:
            vid = v.get("vehicle_id") or v.get("id") or (v.get("announcement") or {}).get("vehicle_id")
            vehicles[vid] = {"states_accepted": v.get("states_accepted"),
                             "states_rejected": v.get("states_rejected")}
        return {"rejected": ing.get("rejected") or {}, "malformed": ing.get("malformed") or {},
                "announcements": ing.get("announcements"), "states_accepted": ing.get("states_accepted"),
                "vehicles": vehicles}


def delta(a, b):
    """What changed between two snapshots that a leaked case would change."""
    if "error" in a or "error" in b:
        return {"error": a.get("error") or b.get("error")}
    out = {}
    for k in ("rejected", "malformed"):
        for r, n in b[k].items():
            # Refused handshakes come from the credential attackers joining meanwhile
            # (Cyclone retries each failed handshake every second): counted refusals of
            # participants that never got in, not a packet case that leaked.
            if r.startswith("security:handshake_refused:"):
                continue
            if n != a[k].get(r, 0):
                out[f"{k}:{r}"] = n - a[k].get(r, 0)
    new = sorted(set(b["vehicles"]) - set(a["vehicles"]))
    if new:
        out["new_vehicles"] = new
    if b["announcements"] != a["announcements"]:
        out["announcements"] = b["announcements"] - a["announcements"]
    for vid, v in b["vehicles"].items():
        if vid in a["vehicles"] and v["states_rejected"] != a["vehicles"][vid]["states_rejected"]:
            out[f"states_rejected:{vid}"] = v["states_rejected"] - a["vehicles"][vid]["states_rejected"]
    return out


# ------------------------------------------------------------------ main

def wait_file(path, timeout):
    end = time.time() + timeout
    while time.time() < end:
        if os.path.exists(path):
            return True
        time.sleep(0.1)
    return False


def packets(a):
    rng = random.Random(a.seed)
    cap = Capture(a.vehicle_cert, a.station_cert)
    send = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    send.bind(("127.0.0.1", 0))
    send.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
    send.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
    send.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
    cap.own_ports.add(send.getsockname()[1])
    cap.start()
    w = a.work
    open(os.path.join(w, "sniff.ready"), "w").close()
    api = Api(a.api, a.token)
    result = {"cases": {}, "sent_errors": {}, "windows": {}, "notes": []}

    def fail(msg):
        result["error"] = msg
        log(msg)
        json.dump(result, open(os.path.join(w, "packets.json"), "w"))
        open(os.path.join(w, "attacking"), "w").close()
        sys.exit(1)

    if not wait_file(os.path.join(w, "run1.done"), 90):
        fail("the vehicle's first session never ended (run1.done)")
    if not cap.sessions:
        fail("no SPDP of the vehicle's first session seen on lo")
    old = cap.sessions[0]
    # The second session: a new participant of the same vehicle.
    end = time.time() + 40
    while time.time() < end and len(cap.sessions) < 2:
        time.sleep(0.1)
    if len(cap.sessions) < 2:
        fail("the vehicle's second session never appeared on lo")
    live = cap.sessions[1]
    if cap.station_prefix is None:
        fail("the station's SPDP (with its identity token) was never seen")
    # Let the handshake finish and the session's protected traffic flow.
    end = time.time() + 40
    while time.time() < end:
        sec = [p for _, p in cap.packets(live) if any(s[0] == SEC_BODY for s in submessages(p))]
        if len(sec) >= 20:
            break
        time.sleep(0.2)
    else:
        fail("the vehicle's second session sent no protected submessages")
    station_locs = set(cap.station_locs)
    log(f"station locators {sorted(station_locs)}")

    def to_station(pkts):
        """The vehicle's datagrams that went to the station (unicast) or to a group."""
        out = []
        for dst, d in pkts:
            if dst in station_locs or 224 <= int(dst[0].split(".")[0]) <= 239:
                out.append((dst, d))
        return out

    old_pkts = to_station(cap.packets(old))
    if not old_pkts:
        fail("nothing of the first session went to the station")
    default_dst = sorted(station_locs)[-1] if station_locs else old_pkts[0][0]
    open(os.path.join(w, "attacking"), "w").close()
    scale = a.scale
    plan = [
        ("replay-live", 1500), ("replay-old", 1000), ("flip-header", 700),
        ("flip-submsg-header", 900), ("flip-sec-prefix", 900), ("flip-ciphertext", 1300),
        ("flip-mac", 1100), ("flip-clear", 700), ("truncated", 900), ("extended", 900),
        ("readdressed", 800), ("forged-packet", 800),
    ]
    state_cdr = bytes.fromhex(a.state_cdr) if a.state_cdr else rng.randbytes(112)
    prev = api.snapshot()
    dests = {}
    neighbours = [p for p in cap.others] + [cap.station_prefix, old]
    for kind, n in plan:
        n = max(1, int(n * scale))
        t0 = time.time()
        sent = errors = 0
        if kind == "forged-packet":
            dst_pool = sorted(station_locs) or [default_dst]
            cases = [(rng.choice(dst_pool), d) for d in forged_cases(live, cap.station_prefix, state_cdr, rng, n)]
        else:
            cases = None
        i = 0
        while sent + errors < n:
            if cases is not None:
                dst, d = cases[i]
                i += 1
            else:
                src = old_pkts if kind == "replay-old" else to_station(cap.packets(live)[-4000:])
                dst, orig = rng.choice(src)
                if kind.startswith("replay"):
                    d = orig
                elif kind.startswith("flip"):
                    d = pick_flip(kind, orig, rng)
                    if d is None:
                        continue
                elif kind == "truncated":
                    d = truncate(orig, rng)
                elif kind == "extended":
                    d = extend(orig, rng)
                else:
                    d = readdress(orig, rng, neighbours)
            try:
                send.sendto(d, dst)
                sent += 1
                dests[dst[0] + ":" + str(dst[1])] = dests.get(dst[0] + ":" + str(dst[1]), 0) + 1
            except OSError:
                errors += 1
            if (sent + errors) % 40 == 0:
                time.sleep(0.04 / a.speed)
        time.sleep(a.settle)
        now = api.snapshot()
        result["cases"][kind] = sent
        result["sent_errors"][kind] = errors
        result["windows"][kind] = {"from": t0, "to": time.time(), "delta": delta(prev, now)}
        log(f"{kind}: {sent} sent ({errors} send errors) in {time.time() - t0:.1f} s, station delta {result['windows'][kind]['delta'] or 'none'}")
        prev = now
    result["sessions"] = [p.hex() for p in cap.sessions]
    result["station_prefix"] = cap.station_prefix.hex()
    result["station_locators"] = sorted(station_locs)
    result["destinations"] = dests
    result["captured"] = {"old": len(old_pkts), "live": len(cap.packets(live))}
    cap.stop = True
    json.dump(result, open(os.path.join(w, "packets.json"), "w"), indent=1)
    return 0


def main():
    p = argparse.ArgumentParser()
    sp = p.add_subparsers(dest="cmd", required=True)
    k = sp.add_parser("packets")
    k.add_argument("--vehicle-cert", required=True, help="the legitimate vehicle's cert.pem")
    k.add_argument("--station-cert", required=True, help="the station's cert.pem")
    k.add_argument("--api", required=True)
    k.add_argument("--token", required=True)
    k.add_argument("--work", required=True)
    k.add_argument("--scale", type=float, default=1.0, help="multiplies every kind's case count")
    k.add_argument("--speed", type=float, default=1.0, help="injection rate factor (1: ~1000/s)")
    k.add_argument("--settle", type=float, default=1.0, help="s after each kind before reading the station")
    k.add_argument("--seed", type=int, default=20)
    k.add_argument("--state-cdr", default="", help="hex of a StateVector (XCDR1 with header) for forged DATA")
    a = p.parse_args()
    return packets(a)


if __name__ == "__main__":
    sys.exit(main())
