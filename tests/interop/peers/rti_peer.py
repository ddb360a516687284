#!/usr/bin/env python3
"""Shoal interop peer on RTI Connext DDS (PyPI `rticonnextdds-connector`).

Types and QoS live in shoal_rti.xml next to this file (checked against
idl/shoal.idl by tests/interop/check_rti_xml.py). All readers and writers use
XCDR_DATA_REPRESENTATION (plain XCDR1 CDR), the only representation Shoal
reads. The connector wheel bundles the Connext 6.1.2 libraries and needs no
license file.

Subcommands (same interface as cyclone_peer.py and the Fast DDS peer):
  publish-state  --vehicle-id ID --count N --rate HZ [--linger S]
  subscribe-task --vehicle-id ID --expect N --timeout S
  publish-task   --vehicle-id ID --task-id T [--linger S] [--wait-match S]
  subscribe-state --expect N --timeout S [--vehicle-id ID] [--expect-announcements K]
"""

import json
import os
import re
import sys
import tempfile
import time
import xml.etree.ElementTree as ET

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import peer_common as pc  # noqa: E402

import rticonnextdds_connector as rti  # noqa: E402

PEER = "rti-connext"
XML = os.path.join(HERE, "shoal_rti.xml")
LIB = "ShoalParticipantLibrary"

# Member order of each exchanged type (IDL order), and enum members.
FIELDS_STATE = list(pc.state_vector("x", 0))
FIELDS_ANN = list(pc.announcement("x", "x"))
FIELDS_TASK = list(pc.goto_task("x", "x"))
ENUMS = {
    "kind@ann": pc.VEHICLE_KIND,
    "links@ann": pc.LINK_KIND,
    "kind@task": pc.TASK_KIND,
}


def enum_to_ord(names, v):
    return names.index(v) if isinstance(v, str) else int(v)


def enum_to_name(names, v):
    if isinstance(v, str):
        return v  # some connector versions already return the enumerator name
    return names[int(v)]


class Conn:
    """An RTI Connector for one participant of shoal_rti.xml on --domain."""

    def __init__(self, participant: str, domain: int):
        with open(XML, encoding="utf-8") as f:
            text = f.read()
        ET.fromstring(text)  # fail early, with a clear message, on malformed XML
        text, n = re.subn(r'(<domain\s+name="Shoal"\s+domain_id=")\d+(")', rf"\g<1>{int(domain)}\g<2>", text)
        if n != 1:
            raise SystemExit(f"{XML}: cannot find <domain name=\"Shoal\" domain_id=...>")
        fd, self.path = tempfile.mkstemp(prefix="shoal_rti_", suffix=".xml")
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        self.c = rti.Connector(config_name=f"{LIB}::{participant}", url=self.path)

    def close(self):
        try:
            self.c.close()
        finally:
            try:
                os.unlink(self.path)
            except OSError:
                pass


def wait_matched(output, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end and not pc.Stop.flag:
        if len(output.matched_subscriptions) > 0:
            return True
        time.sleep(0.05)
    return False


def write(output, sample: dict):
    output.instance.set_dictionary(sample)
    output.write()


def ann_out(d: dict) -> dict:
    d = dict(d)
    d["kind"] = enum_to_ord(pc.VEHICLE_KIND, d["kind"])
    d["links"] = [enum_to_ord(pc.LINK_KIND, x) for x in d["links"]]
    return d


def ann_in(d: dict) -> dict:
    out = {k: d.get(k) for k in FIELDS_ANN}
    out["kind"] = enum_to_name(pc.VEHICLE_KIND, out["kind"])
    out["links"] = [enum_to_name(pc.LINK_KIND, x) for x in (out["links"] or [])]
    out["capabilities"] = out["capabilities"] or []
    out["sensors"] = out["sensors"] or []
    return out


def task_out(d: dict) -> dict:
    d = dict(d)
    d["kind"] = enum_to_ord(pc.TASK_KIND, d["kind"])
    return d


def task_in(d: dict) -> dict:
    out = {k: d.get(k) for k in FIELDS_TASK}
    out["kind"] = enum_to_name(pc.TASK_KIND, out["kind"])
    out["area"] = [{"latitude_deg": float(p["latitude_deg"]), "longitude_deg": float(p["longitude_deg"])}
                   for p in (out["area"] or [])]
    return normalize(out)


def state_in(d: dict) -> dict:
    return normalize({k: d.get(k) for k in FIELDS_STATE})


def normalize(d: dict) -> dict:
    # The connector hands numbers over as JSON; keep int64 as int, doubles as float.
    for k, v in d.items():
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            d[k] = int(v) if k.endswith("_ms") else float(v)
    return d


def take_valid(inp, wait_s: float = 0.1):
    try:
        inp.wait(int(wait_s * 1000))
    except rti.TimeoutError:
        return []
    inp.take()
    return [s.get_dictionary() for s in inp.samples.valid_data_iter]


# ---------------------------------------------------------------- commands


def cmd_publish_state(a) -> int:
    c = Conn("StatePublisher", a.domain)
    try:
        ann_w = c.c.get_output("Pub::AnnouncementWriter")
        w = c.c.get_output("Pub::StateWriter")
        write(ann_w, ann_out(pc.announcement(a.vehicle_id, PEER)))
        pc.log(PEER, f"announced {a.vehicle_id}")
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
            write(w, pc.state_vector(a.vehicle_id, i))
            sent += 1
            if i + 1 < a.count and not pc.sleep_unless_stopped(period):
                break
        if not pc.Stop.flag:
            try:
                w.wait(int(a.linger * 1000))  # until all matched readers acked
            except rti.TimeoutError:
                pc.log(PEER, "not all samples acknowledged before --linger ran out")
            pc.sleep_unless_stopped(a.linger)
        pc.emit(f"published {sent}")
        return 0 if sent == a.count else pc.Stop.code
    finally:
        c.close()


def cmd_publish_task(a) -> int:
    c = Conn("TaskPublisher", a.domain)
    try:
        w = c.c.get_output("Pub::TaskWriter")
        if a.wait_match > 0 and not wait_matched(w, a.wait_match):
            pc.log(PEER, "no TaskAssignment reader matched yet; publishing anyway (transient-local)")
        write(w, task_out(pc.goto_task(a.task_id, a.vehicle_id)))
        pc.log(PEER, f"published task {a.task_id} for {a.vehicle_id}; lingering {a.linger} s")
        pc.sleep_unless_stopped(a.linger)
        pc.emit("published 1")
        return 0
    finally:
        c.close()


def cmd_subscribe_task(a) -> int:
    c = Conn("TaskSubscriber", a.domain)
    try:
        r = c.c.get_input("Sub::TaskReader")
        got = 0
        end = time.monotonic() + a.timeout
        while got < a.expect:
            if pc.Stop.flag:
                return pc.Stop.code
            if time.monotonic() > end:
                pc.log(PEER, f"timeout: received {got} of {a.expect} TaskAssignments for {a.vehicle_id}")
                return 1
            for d in take_valid(r):
                s = task_in(d)
                if s["vehicle_id"] == a.vehicle_id and got < a.expect:
                    pc.emit_json(s)
                    got += 1
        return 0
    finally:
        c.close()


def cmd_subscribe_state(a) -> int:
    c = Conn("StateSubscriber", a.domain)
    try:
        r = c.c.get_input("Sub::StateReader")
        ra = c.c.get_input("Sub::AnnouncementReader")
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
            if a.expect_announcements > 0:
                for d in take_valid(ra, 0.0):
                    s = normalize(ann_in(d))
                    if a.vehicle_id is None or s["vehicle_id"] == a.vehicle_id:
                        pc.emit("announcement " + json.dumps(s, separators=(",", ":")))
                        got_ann += 1
            for d in take_valid(r, 0.05):
                s = state_in(d)
                if (a.vehicle_id is None or s["vehicle_id"] == a.vehicle_id) and got < a.expect:
                    pc.emit_json(s)
                    got += 1
        return 0
    finally:
        c.close()


COMMANDS = {
    "publish-state": cmd_publish_state,
    "publish-task": cmd_publish_task,
    "subscribe-task": cmd_subscribe_task,
    "subscribe-state": cmd_subscribe_state,
}


def main(argv=None) -> int:
    a = pc.parser("rti_peer.py").parse_args(argv)
    pc.Stop.install()
    return COMMANDS[a.cmd](a)


if __name__ == "__main__":
    sys.exit(main())
