#!/usr/bin/env python3
"""Reads a Shoal recording with the reference MCAP reader (the `mcap` package) and prints
what it found as one JSON object, for the recorder's tests to compare with what was sent.

Usage: check_mcap.py FILE [summary|stream]

  summary  the file must be complete: the summary (statistics, chunk indexes) is read and
           messages are read through it, as Foxglove does with a local file;
  stream   the file is read front to back without the summary, as far as it goes (a
           recorder killed mid-file); a read error is reported, not raised.

Output: {"profile", "library", "schemas": {id: {name, encoding, idl_has_module}},
"channels": {topic: {schema, message_encoding}}, "counts": {topic: n},
"statistics_count" (summary mode), "cdr_headers": [hex of the distinct first 4 bytes],
"state_vectors": [[vehicle_id, timestamp_ms, latitude_bits], ...] (the IEEE 754 bits of
latitude_deg as an integer, so that no decimal rendering blurs them), "error": null | text}
"""

import json
import struct
import sys

from mcap.reader import make_reader
from mcap.records import Channel, Header, Message, Schema
from mcap.stream_reader import StreamReader


def state_vector(data: bytes):
    """vehicle_id, timestamp_ms, the bits of latitude_deg of a CDR_LE StateVector (XCDR1, plain):
    decoded here by hand from the IDL's layout, independently of Shoal's serde code."""
    body = data[4:]
    (n,) = struct.unpack_from("<I", body, 0)
    vehicle_id = body[4 : 4 + n - 1].decode()
    off = 4 + n
    off = (off + 7) & ~7  # int64 aligned to 8 from the start of the body
    timestamp_ms, latitude_bits = struct.unpack_from("<qQ", body, off)
    return [vehicle_id, timestamp_ms, latitude_bits]


def main() -> int:
    path = sys.argv[1]
    mode = sys.argv[2] if len(sys.argv) > 2 else "summary"
    out = {
        "profile": None,
        "library": None,
        "schemas": {},
        "channels": {},
        "counts": {},
        "cdr_headers": [],
        "state_vectors": [],
        "error": None,
    }
    schemas = {}
    channels = {}
    headers = set()

    def schema(s):
        schemas[s.id] = s
        out["schemas"][str(s.id)] = {
            "name": s.name,
            "encoding": s.encoding,
            "idl_has_module": b"module shoal" in s.data,
        }

    def channel(c):
        channels[c.id] = c
        out["channels"][c.topic] = {
            "schema": schemas[c.schema_id].name if c.schema_id in schemas else None,
            "message_encoding": c.message_encoding,
        }
        out["counts"].setdefault(c.topic, 0)

    def message(topic, data):
        out["counts"][topic] = out["counts"].get(topic, 0) + 1
        headers.add(data[:4].hex())
        if topic == "shoal/state_vector":
            out["state_vectors"].append(state_vector(data))

    with open(path, "rb") as f:
        if mode == "summary":
            reader = make_reader(f, validate_crcs=True)
            header = reader.get_header()
            out["profile"], out["library"] = header.profile, header.library
            summary = reader.get_summary()
            if summary is None:
                out["error"] = "no summary"
            else:
                for s in summary.schemas.values():
                    schema(s)
                for c in summary.channels.values():
                    channel(c)
                out["statistics_count"] = summary.statistics.message_count
                for _schema, chan, msg in reader.iter_messages(log_time_order=False):
                    message(chan.topic, msg.data)
        else:
            try:
                for record in StreamReader(f, validate_crcs=True).records:
                    if isinstance(record, Header):
                        out["profile"], out["library"] = record.profile, record.library
                    elif isinstance(record, Schema):
                        schema(record)
                    elif isinstance(record, Channel):
                        channel(record)
                    elif isinstance(record, Message):
                        message(channels[record.channel_id].topic, record.data)
            except Exception as e:  # the point of stream mode: how far it gets
                out["error"] = f"{type(e).__name__}: {e}"
    out["cdr_headers"] = sorted(headers)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
