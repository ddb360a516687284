#!/usr/bin/env python3
"""Watches RTPS traffic on `lo` (inside the test network namespace) and checks
the data representation every vendor actually puts on the wire.

For each DATA submessage written by a user-defined writer (entity kind
0x02/0x03, i.e. not a builtin discovery endpoint) it records the
encapsulation identifier of the serialized payload: 0x0001 CDR_LE / 0x0000
CDR_BE are plain XCDR1 (what Shoal reads); 0x0006/0x0007 (CDR2),
0x0008/0x0009 (D_CDR2), 0x000a/0x000b (PL_CDR2) are XCDR2; 0x0002/0x0003 are
PL_CDR (XCDR1 mutable).

  rtps_sniff.py [--duration S] [--expect-vendors rti,cyclonedds,fastdds]

Runs until SIGTERM/SIGINT (or --duration), then prints a JSON summary on
stdout. Exits 1 if any user sample was not plain XCDR1 (0x0000/0x0001) or an
expected vendor wrote no user sample. Needs CAP_NET_RAW (root).
"""

import argparse
import json
import signal
import socket
import struct
import sys
import time

VENDORS = {0x0101: "rti", 0x0110: "cyclonedds", 0x010F: "fastdds", 0x0112: "rustdds"}
ENCAPS = {0x0000: "CDR_BE", 0x0001: "CDR_LE", 0x0002: "PL_CDR_BE", 0x0003: "PL_CDR_LE",
          0x0006: "CDR2_BE", 0x0007: "CDR2_LE", 0x0008: "D_CDR2_BE", 0x0009: "D_CDR2_LE",
          0x000A: "PL_CDR2_BE", 0x000B: "PL_CDR2_LE"}
ETH_P_IP = 0x0800
DATA = 0x15
DATA_FRAG = 0x16

stop = False


def on_signal(*_):
    global stop
    stop = True


def parse_rtps(msg, summary):
    if len(msg) < 20 or msg[:4] != b"RTPS":
        return
    vendor = struct.unpack(">H", msg[6:8])[0]
    vname = VENDORS.get(vendor, f"0x{vendor:04x}")
    off = 20
    while off + 4 <= len(msg):
        sid, flags = msg[off], msg[off + 1]
        le = flags & 1
        length = struct.unpack("<H" if le else ">H", msg[off + 2:off + 4])[0]
        body = off + 4
        end = len(msg) if length == 0 else body + length
        if sid in (DATA, DATA_FRAG) and end - body >= 20:
            octets_to_qos = struct.unpack("<H" if le else ">H", msg[body + 2:body + 4])[0]
            writer_id = msg[body + 8:body + 12]
            kind = writer_id[3]
            user = (kind & 0xC0) == 0 and (kind & 0x3F) in (0x02, 0x03)
            # octetsToInlineQos counts from the end of its own field.
            p = body + 4 + octets_to_qos
            if sid == DATA:
                has_payload = (flags & 0x0C) != 0  # D or K flag
            else:
                # DATA_FRAG: the encapsulation is in fragment 1 only.
                frag_start = struct.unpack("<I" if le else ">I", msg[body + 20:body + 24])[0]
                has_payload = frag_start == 1
            if flags & 0x02:  # inline QoS: skip the parameter list
                while p + 4 <= end:
                    pid, plen = struct.unpack("<HH" if le else ">HH", msg[p:p + 4])
                    p += 4 + plen
                    if pid == 0x0001:
                        break
            if user and has_payload and p + 2 <= end:
                enc = struct.unpack(">H", msg[p:p + 2])[0]
                key = ENCAPS.get(enc, f"0x{enc:04x}")
                v = summary.setdefault(vname, {})
                v[key] = v.get(key, 0) + 1
        if length == 0:
            break
        off = end


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=0.0)
    ap.add_argument("--expect-vendors", default="")
    ap.add_argument("--ready-file", default="", help="touch this file once capturing")
    a = ap.parse_args()
    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    s = socket.socket(socket.AF_PACKET, socket.SOCK_DGRAM, socket.htons(ETH_P_IP))
    s.bind(("lo", 0))
    s.settimeout(0.2)
    if a.ready_file:
        open(a.ready_file, "w").close()
    summary = {}
    end = time.monotonic() + a.duration if a.duration > 0 else None
    while not stop and (end is None or time.monotonic() < end):
        try:
            pkt, addr = s.recvfrom(65535)
        except socket.timeout:
            continue
        except InterruptedError:
            continue
        if addr[2] == socket.PACKET_OUTGOING:
            continue  # every loopback packet is seen twice; count the incoming copy
        if len(pkt) < 28 or pkt[9] != 17:  # IPv4 / UDP only
            continue
        ihl = (pkt[0] & 0x0F) * 4
        parse_rtps(pkt[ihl + 8:], summary)

    bad = {v: {k: n for k, n in encs.items() if k not in ("CDR_LE", "CDR_BE")}
           for v, encs in summary.items()}
    bad = {v: e for v, e in bad.items() if e}
    missing = [v for v in a.expect_vendors.split(",") if v and v not in summary]
    print(json.dumps({"user_data_encapsulations": summary, "not_xcdr1": bad,
                      "vendors_without_user_data": missing}, sort_keys=True))
    return 1 if bad or missing else 0


if __name__ == "__main__":
    sys.exit(main())
