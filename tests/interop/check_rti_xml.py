#!/usr/bin/env python3
"""Asserts that the RTI XML types in tests/interop/peers/shoal_rti.xml agree
with idl/shoal.idl: same enums (enumerators, order), same structs (names,
extensibility, member names, order, types, string and sequence bounds, keys),
same constants, and that every topic the XML registers carries the type the
IDL header assigns to it.

  check_rti_xml.py [--idl idl/shoal.idl] [--xml tests/interop/peers/shoal_rti.xml]

Prints each mismatch and exits 1 if there is any; exits 0 otherwise. The IDL
parser is a small regex parser that covers the constructs shoal.idl uses
(module, const, enum, @final/@appendable/@mutable struct, @key members,
string<N>, sequence<T, N>, primitive types); anything else is an error.
"""

import argparse
import os
import re
import sys
import xml.etree.ElementTree as ET

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.normpath(os.path.join(HERE, "..", ".."))

PRIMS = {
    # IDL name -> canonical
    "int64": "int64", "long long": "int64", "uint64": "uint64", "unsigned long long": "uint64",
    "int32": "int32", "long": "int32", "uint32": "uint32", "unsigned long": "uint32",
    "int16": "int16", "short": "int16", "uint16": "uint16", "unsigned short": "uint16",
    "double": "float64", "float": "float32", "boolean": "boolean", "octet": "octet",
    "char": "char8", "int8": "int8", "uint8": "uint8",
}
XML_PRIMS = {
    # RTI XML type attribute -> canonical
    "int64": "int64", "longLong": "int64", "uint64": "uint64", "unsignedLongLong": "uint64",
    "int32": "int32", "long": "int32", "uint32": "uint32", "unsignedLong": "uint32",
    "int16": "int16", "short": "int16", "uint16": "uint16", "unsignedShort": "uint16",
    "float64": "float64", "double": "float64", "float32": "float32", "float": "float32",
    "boolean": "boolean", "octet": "octet", "byte": "octet", "char8": "char8", "char": "char8",
    "int8": "int8", "uint8": "uint8",
}


class Model:
    def __init__(self):
        self.enums = {}    # qualified name -> [enumerators]
        self.structs = {}  # qualified name -> {"ext": str, "members": [member dicts]}
        self.consts = {}   # qualified name -> (type, value float/int/str)
        self.topics = {}   # topic name -> qualified type name


def member(name, base, str_bound=None, seq_bound=None, key=False):
    return {"name": name, "type": base, "string_bound": str_bound, "sequence_bound": seq_bound,
            "key": key}


# ------------------------------------------------------------------ IDL


def strip_comments(text):
    text = re.sub(r"/\*.*?\*/", " ", text, flags=re.S)
    return re.sub(r"//[^\n]*", " ", text)


def parse_idl(path):
    raw = open(path, encoding="utf-8").read()
    m = Model()
    # Topic table in the header comment: "//   shoal/x   TypeName   key ..."
    for tm in re.finditer(r"^//\s+(shoal/\w+)\s+(\w+)\s+key\s", raw, flags=re.M):
        m.topics[tm.group(1)] = "shoal::" + tm.group(2)
    text = strip_comments(raw)
    mm = re.search(r"\bmodule\s+(\w+)\s*\{(.*)\}\s*;\s*$", text, flags=re.S)
    if not mm:
        raise SystemExit(f"{path}: no module found")
    mod, body = mm.group(1), mm.group(2)
    q = lambda n: f"{mod}::{n}"  # noqa: E731

    for cm in re.finditer(r"\bconst\s+(\w[\w ]*?)\s+(\w+)\s*=\s*([^;]+);", body):
        m.consts[q(cm.group(2))] = (PRIMS.get(cm.group(1).strip(), cm.group(1).strip()),
                                    float(cm.group(3)))
    for em in re.finditer(r"\benum\s+(\w+)\s*\{([^}]*)\}\s*;", body):
        m.enums[q(em.group(1))] = [e.strip() for e in em.group(2).split(",") if e.strip()]

    for sm in re.finditer(r"((?:@\w+\s*)*)\bstruct\s+(\w+)\s*\{([^}]*)\}\s*;", body):
        annots = re.findall(r"@(\w+)", sm.group(1))
        ext = next((a for a in annots if a in ("final", "appendable", "mutable")), "appendable")
        members = []
        for decl in sm.group(3).split(";"):
            decl = " ".join(decl.split())
            if not decl:
                continue
            key = False
            while decl.startswith("@"):
                a, _, decl = decl.partition(" ")
                if a == "@key":
                    key = True
                else:
                    raise SystemExit(f"{path}: unsupported member annotation {a} in {sm.group(2)}")
            dm = re.fullmatch(r"(.+?)\s+(\w+)", decl)
            if not dm:
                raise SystemExit(f"{path}: cannot parse member '{decl}' in {sm.group(2)}")
            members.append(parse_idl_type(dm.group(1), dm.group(2), key, q, path))
        m.structs[q(sm.group(2))] = {"ext": ext, "members": members}
    # Resolve bare names to enum/struct.
    for s in m.structs.values():
        for mb in s["members"]:
            t = mb["type"]
            if t.startswith("ref:"):
                name = t[4:]
                if name in m.enums:
                    mb["type"] = "enum:" + name
                elif name in m.structs:
                    mb["type"] = "struct:" + name
                else:
                    raise SystemExit(f"{path}: unknown type {name}")
    return m


def parse_idl_type(t, name, key, q, path):
    t = " ".join(t.replace("< ", "<").replace(" >", ">").split())
    sq = re.fullmatch(r"sequence<\s*(.+?)\s*(?:,\s*(\d+))?\s*>", t)
    if sq:
        inner = parse_idl_type(sq.group(1), name, key, q, path)
        inner["sequence_bound"] = int(sq.group(2)) if sq.group(2) else None
        if inner["sequence_bound"] is None:
            inner["sequence_bound"] = "unbounded"
        return inner
    st = re.fullmatch(r"string(?:<\s*(\d+)\s*>)?", t)
    if st:
        return member(name, "string", int(st.group(1)) if st.group(1) else "unbounded", None, key)
    if t in PRIMS:
        return member(name, PRIMS[t], None, None, key)
    if re.fullmatch(r"\w+(::\w+)*", t):
        return member(name, "ref:" + (t if "::" in t else q(t)), None, None, key)
    raise SystemExit(f"{path}: unsupported type '{t}' for member {name}")


# ------------------------------------------------------------------ XML


def parse_xml(path):
    root = ET.parse(path).getroot()
    m = Model()
    types = root.find("types")
    if types is None:
        raise SystemExit(f"{path}: no <types>")

    def walk(el, scope):
        for c in el:
            tag = c.tag
            if tag == "module":
                walk(c, scope + [c.get("name")])
                continue
            qn = "::".join(scope + [c.get("name")])
            if tag == "const":
                t = XML_PRIMS.get(c.get("type"), c.get("type"))
                m.consts[qn] = (t, float(c.get("value")))
            elif tag == "enum":
                vals = []
                for i, e in enumerate(c.findall("enumerator")):
                    if e.get("value") is not None and int(e.get("value")) != i:
                        raise SystemExit(f"{path}: {qn}.{e.get('name')} has value {e.get('value')}, "
                                         f"IDL ordinal is {i}")
                    vals.append(e.get("name"))
                m.enums[qn] = vals
            elif tag == "struct":
                mem = []
                for e in c.findall("member"):
                    mem.append(xml_member(e, scope, path, qn))
                m.structs[qn] = {"ext": c.get("extensibility", "appendable"), "members": mem}
            else:
                raise SystemExit(f"{path}: unsupported element <{tag}> in <types>")
    walk(types, [])

    # Topics and their registered types (all domains).
    for dom in root.iter("domain"):
        regs = {r.get("name"): r.get("type_ref") or r.get("name") for r in dom.findall("register_type")}
        for t in dom.findall("topic"):
            reg = t.get("register_type_ref")
            if regs.get(reg) != reg:
                raise SystemExit(f"{path}: topic {t.get('name')}: register_type '{reg}' must be "
                                 "registered under its own (module-qualified) type name")
            m.topics[t.get("name")] = regs[reg]
    for s in m.structs.values():
        for mb in s["members"]:
            t = mb["type"]
            if t.startswith("ref:"):
                name = t[4:]
                mb["type"] = ("enum:" + name if name in m.enums else
                              "struct:" + name if name in m.structs else "unknown:" + name)
    return m


def xml_member(e, scope, path, qn):
    name = e.get("name")
    t = e.get("type")
    key = e.get("key", "false").lower() == "true"
    seq = e.get("sequenceMaxLength")
    seq_bound = None if seq is None else ("unbounded" if seq == "-1" else int(seq))
    if e.get("arrayDimensions"):
        raise SystemExit(f"{path}: {qn}.{name}: arrays are not in shoal.idl")
    if t == "string":
        sl = e.get("stringMaxLength")
        sb = "unbounded" if sl in (None, "-1") else int(sl)
        return member(name, "string", sb, seq_bound, key)
    if t == "nonBasic":
        ref = e.get("nonBasicTypeName")
        if "::" not in ref:
            ref = "::".join(scope + [ref])
        return member(name, "ref:" + ref, None, seq_bound, key)
    if t in XML_PRIMS:
        return member(name, XML_PRIMS[t], None, seq_bound, key)
    raise SystemExit(f"{path}: {qn}.{name}: unsupported XML type '{t}'")


# ------------------------------------------------------------------ compare


def describe(mb):
    s = mb["type"]
    if mb["string_bound"] is not None:
        s += f"<{mb['string_bound']}>"
    if mb["sequence_bound"] is not None:
        s = f"sequence<{s}, {mb['sequence_bound']}>"
    return ("@key " if mb["key"] else "") + s + " " + mb["name"]


def compare(idl, xml):
    errs = []
    for n in sorted(set(idl.enums) | set(xml.enums)):
        if n not in xml.enums:
            errs.append(f"enum {n}: missing in XML")
        elif n not in idl.enums:
            errs.append(f"enum {n}: in XML but not in IDL")
        elif idl.enums[n] != xml.enums[n]:
            errs.append(f"enum {n}: IDL {idl.enums[n]} != XML {xml.enums[n]}")
    for n in sorted(set(idl.consts) | set(xml.consts)):
        if idl.consts.get(n) != xml.consts.get(n):
            errs.append(f"const {n}: IDL {idl.consts.get(n)} != XML {xml.consts.get(n)}")
    for n in sorted(set(idl.structs) | set(xml.structs)):
        if n not in xml.structs:
            errs.append(f"struct {n}: missing in XML")
            continue
        if n not in idl.structs:
            errs.append(f"struct {n}: in XML but not in IDL")
            continue
        a, b = idl.structs[n], xml.structs[n]
        if a["ext"] != b["ext"]:
            errs.append(f"struct {n}: extensibility IDL {a['ext']} != XML {b['ext']}")
        an = [x["name"] for x in a["members"]]
        bn = [x["name"] for x in b["members"]]
        if an != bn:
            errs.append(f"struct {n}: members IDL {an} != XML {bn}")
        for i, (x, y) in enumerate(zip(a["members"], b["members"])):
            if x != y:
                errs.append(f"struct {n}: member #{i}: IDL '{describe(x)}' "
                            f"!= XML '{describe(y)}'")
    for topic, ty in sorted(xml.topics.items()):
        if topic not in idl.topics:
            errs.append(f"topic {topic}: not listed in the IDL header")
        elif idl.topics[topic] != ty:
            errs.append(f"topic {topic}: IDL type {idl.topics[topic]} != XML {ty}")
    return errs


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--idl", default=os.path.join(REPO, "idl", "shoal.idl"))
    p.add_argument("--xml", default=os.path.join(HERE, "peers", "shoal_rti.xml"))
    a = p.parse_args()
    idl = parse_idl(a.idl)
    xml = parse_xml(a.xml)
    if not idl.structs or not idl.enums:
        print("check_rti_xml: parsed no structs/enums from the IDL", file=sys.stderr)
        return 1
    errs = compare(idl, xml)
    for e in errs:
        print(f"MISMATCH {e}")
    if errs:
        print(f"check_rti_xml: {len(errs)} mismatch(es) between {a.idl} and {a.xml}", file=sys.stderr)
        return 1
    print(f"check_rti_xml: OK: {len(idl.structs)} structs, {len(idl.enums)} enums, "
          f"{len(idl.consts)} consts, {len(xml.topics)} topics agree")
    return 0


if __name__ == "__main__":
    sys.exit(main())
