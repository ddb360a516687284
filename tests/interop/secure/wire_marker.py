#!/usr/bin/env python3
"""Counts UDP datagrams on `lo` (inside a test network namespace) whose payload
contains a marker string, e.g. the peers' announcement name "interop vehicle",
which only ever travels inside user samples. With DDS Security data protection
ENCRYPT it must never be seen in clear.

  wire_marker.py MARKER [--ready-file F]

Runs until SIGTERM/SIGINT, then prints one JSON line: {"rtps": N, "marker": M}
(RTPS datagrams seen, datagrams containing MARKER). Needs CAP_NET_RAW (root).
"""

import argparse
import json
import signal
import socket

ETH_P_ALL = 0x0003
stop = False


def on_signal(*_):
    global stop
    stop = True


def main():
    p = argparse.ArgumentParser()
    p.add_argument("marker")
    p.add_argument("--ready-file")
    a = p.parse_args()
    marker = a.marker.encode()
    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
    s.bind(("lo", 0))
    s.settimeout(0.2)
    if a.ready_file:
        open(a.ready_file, "w").close()
    rtps = hits = 0
    while not stop:
        try:
            frame, addr = s.recvfrom(65535)
        except (socket.timeout, InterruptedError):
            continue
        if addr[2] == socket.PACKET_OUTGOING:  # lo shows each datagram twice
            continue
        if b"RTPS" not in frame[:80]:
            continue
        rtps += 1
        if marker in frame:
            hits += 1
    print(json.dumps({"rtps": rtps, "marker": hits}))


if __name__ == "__main__":
    main()
