#!/usr/bin/env python3
"""Reads Shoal's acoustic recordings (PREFIX-acoustic-*.mcap) with the reference MCAP reader
(the `mcap` package), as Foxglove reads a local file, and prints what it found as one JSON
object, for the recorder's end-to-end tests to check.

Usage: check_acoustic_mcap.py FILE...

Each file must be complete (its summary is read, messages through it, CRCs checked). Every
message is parsed as JSON and, when the `jsonschema` package is importable (the test venv
has it through schemathesis), validated against its channel's schema.

Output: {"files", "schemas": {topic: {name, encoding, title}},
"message_encodings": {topic: encoding}, "counts": {topic: n}, "directions": {dir: n},
"events": {event: n}, "pdu_types": {type: n}, "decode_errors": n,
"sent_ids": [message ids of sent frames], "event_ids": [message ids of link events],
"received_from": [distinct src of received frames], "rssi_seen": bool,
"log_times_ordered": bool, "validated": bool, "invalid": [first errors]}
"""

import json
import sys

from mcap.reader import make_reader

try:
    import jsonschema
except ImportError:  # validated stays false; the test decides whether that is enough
    jsonschema = None


def main() -> int:
    out = {
        "files": 0,
        "schemas": {},
        "message_encodings": {},
        "counts": {},
        "directions": {},
        "events": {},
        "pdu_types": {},
        "decode_errors": 0,
        "sent_ids": [],
        "event_ids": [],
        "received_from": [],
        "rssi_seen": False,
        "log_times_ordered": True,
        "validated": jsonschema is not None,
        "invalid": [],
    }
    validators = {}
    last = 0
    received_from = set()

    def bump(table, key):
        table[key] = table.get(key, 0) + 1

    for path in sys.argv[1:]:
        out["files"] += 1
        with open(path, "rb") as f:
            reader = make_reader(f, validate_crcs=True)
            summary = reader.get_summary()
            if summary is None:
                raise SystemExit(f"{path}: no summary")
            for channel in summary.channels.values():
                schema = summary.schemas[channel.schema_id]
                document = json.loads(schema.data)
                out["schemas"][channel.topic] = {
                    "name": schema.name,
                    "encoding": schema.encoding,
                    "title": document.get("title"),
                }
                out["message_encodings"][channel.topic] = channel.message_encoding
                if jsonschema is not None and channel.topic not in validators:
                    cls = jsonschema.validators.validator_for(document)
                    cls.check_schema(document)
                    validators[channel.topic] = cls(document)
            for _schema, channel, message in reader.iter_messages(log_time_order=False):
                topic = channel.topic
                bump(out["counts"], topic)
                if message.log_time < last:
                    out["log_times_ordered"] = False
                last = message.log_time
                body = json.loads(message.data)
                if topic in validators:
                    for error in validators[topic].iter_errors(body):
                        if len(out["invalid"]) < 5:
                            out["invalid"].append(f"{topic}: {error.message}")
                if topic == "acoustic/frame":
                    bump(out["directions"], body["direction"])
                    if body["direction"] == "sent":
                        out["sent_ids"].append(body["message_id"])
                    else:
                        received_from.add(body["src"])
                        if "rssi_db" in body:
                            out["rssi_seen"] = True
                    for pdu in body.get("pdus", []):
                        bump(out["pdu_types"], pdu["type"])
                    if "decode_error" in body:
                        out["decode_errors"] += 1
                elif topic == "acoustic/link_event":
                    bump(out["events"], body["event"])
                    out["event_ids"].append(body["message_id"])
    out["received_from"] = sorted(received_from)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
