#!/usr/bin/env python3
"""Looks for known values in clear in the RTPS traffic on `lo` (inside a test network
namespace), submessage by submessage.

  rtps_plaintext.py [--text S]... [--f64 X]... [--ready-file F]

Runs until SIGTERM/SIGINT, then prints one JSON line:

  {"rtps": datagrams, "user_data": DATA/DATA_FRAG submessages of user writers in clear,
   "builtin_data": the same for builtin writers (discovery, handshake, ...),
   "secured": SEC_BODY submessages (a protected submessage each),
   "user_hits": {marker: n}, "builtin_hits": {marker: n}}

A marker is a string (--text, e.g. a vehicle id) or a float64 (--f64, e.g. a latitude),
searched in both byte orders. A user writer's entity kind has its two top bits clear
(RTPS 2.x 9.3.1.2); builtin writers (0xC?) carry discovery data and, with DDS Security,
the authentication handshake, where certificate subjects and permissions travel in clear
by design. With data and metadata protection ENCRYPT every user DATA is inside a
SEC_BODY, so user_data is 0. Needs CAP_NET_RAW (root).
"""

import argparse
import json
import signal
import socket
import struct

ETH_P_ALL = 0x0003
DATA, DATA_FRAG, SEC_BODY = 0x15, 0x16, 0x30
stop = False


def on_signal(*_):
    global stop
    stop = True


def submessages(rtps):
    """(id, flags, body) of each submessage of one RTPS message."""
    off = 20
    while off + 4 <= len(rtps):
        sid, flags = rtps[off], rtps[off + 1]
        length = struct.unpack("<H" if flags & 1 else ">H", rtps[off + 2:off + 4])[0]
        body_start = off + 4
        # Length 0 means "to the end of the message" for the last submessage (9.4.5.1.3).
        end = len(rtps) if length == 0 else min(body_start + length, len(rtps))
        yield sid, flags, rtps[body_start:end]
        off = end


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--text", action="append", default=[])
    p.add_argument("--f64", action="append", default=[], type=float)
    p.add_argument("--ready-file")
    a = p.parse_args()
    markers = {t: [t.encode()] for t in a.text}
    for x in a.f64:
        markers[repr(x)] = [struct.pack("<d", x), struct.pack(">d", x)]
    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
    s.bind(("lo", 0))
    s.settimeout(0.2)
    if a.ready_file:
        open(a.ready_file, "w").close()
    out = {"rtps": 0, "user_data": 0, "builtin_data": 0, "secured": 0,
           "user_hits": {m: 0 for m in markers}, "builtin_hits": {m: 0 for m in markers}}
    while not stop:
        try:
            frame, addr = s.recvfrom(65535)
        except (socket.timeout, InterruptedError):
            continue
        if addr[2] == socket.PACKET_OUTGOING:  # lo shows each datagram twice
            continue
        # Ethernet (14) + IPv4 + UDP (8)
        if len(frame) < 14 + 20 + 8 or frame[12:14] != b"\x08\x00" or frame[14 + 9] != 17:
            continue
        ihl = (frame[14] & 0x0F) * 4
        rtps = frame[14 + ihl + 8:]
        if rtps[:4] != b"RTPS":
            continue
        out["rtps"] += 1
        for sid, _flags, body in submessages(rtps):
            if sid == SEC_BODY:
                out["secured"] += 1
                continue
            if sid not in (DATA, DATA_FRAG) or len(body) < 12:
                continue
            writer_kind = body[11]  # extraFlags(2) octetsToInlineQos(2) readerId(4) writerId(4)
            kind = "builtin" if writer_kind & 0xC0 == 0xC0 else "user"
            out[kind + "_data"] += 1
            for name, patterns in markers.items():
                if any(pat in body for pat in patterns):
                    out[kind + "_hits"][name] += 1
    print(json.dumps(out))


if __name__ == "__main__":
    main()
