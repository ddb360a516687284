"""Encodes AIS messages with pyais for the shoal-traffic interop test.

Prints one JSON object: {"pyais": VERSION, "messages": [{"type", "lines", "expect"}]},
where `lines` are the NMEA 0183 sentences pyais produced and `expect` the fields given to
it (the values a decoder must read back, within AIS resolution). Types 1, 2, 3, 5 (two
sentences), 18, 19, 24 part A and part B; one MMSI per message (24A and 24B share one).
"""

import json
import sys

import pyais
from pyais import encode_dict


def vdm(data, seq_id=None, channel="A"):
    return encode_dict(
        data, talker_id="AI", sentence_type="VDM", radio_channel=channel, seq_id=seq_id
    )


def position(msg_type, mmsi, lat, lon, speed, course, heading, **extra):
    data = dict(
        type=msg_type, msg_type=msg_type, mmsi=mmsi, lat=lat, lon=lon, speed=speed, course=course,
        heading=heading, **extra,
    )
    expect = dict(mmsi=mmsi, lat=lat, lon=lon, sog_kn=speed, cog_deg=course,
                  heading_deg=None if heading == 511 else heading,
                  klass="A" if msg_type <= 3 else "B")
    return data, expect


def main():
    messages = []
    for msg_type, mmsi, lat, lon, speed, course, heading, status in [
        (1, 230000001, 60.123456, 24.654321, 12.3, 45.6, 44, 0),
        (2, 230000002, -33.8765, 151.2093, 0.0, 0.0, 270, 5),
        (3, 230000003, 51.5, -0.1275, 21.7, 359.9, 359, 7),
    ]:
        data, expect = position(msg_type, mmsi, lat, lon, speed, course, heading,
                                status=status)
        expect["nav_status"] = status
        messages.append(dict(type=msg_type, lines=vdm(data), expect=expect))

    data, expect = position(18, 230000018, -33.5, -70.25, 0.2, 271.3, 511)
    messages.append(dict(type=18, lines=vdm(data, channel="B"), expect=expect))

    data, expect = position(19, 230000019, 60.1, 24.9, 5.5, 123.4, 120)
    data.update(shipname="SEA BEE", ship_type=37, to_bow=8, to_stern=2, to_port=1,
                to_starboard=2)
    expect.update(name="SEA BEE", ship_type=37,
                  dimensions=dict(to_bow=8, to_stern=2, to_port=1, to_starboard=2))
    messages.append(dict(type=19, lines=vdm(data), expect=expect))

    static5 = dict(
        type=5, mmsi=230000005, ais_version=0, imo=9123456, callsign="OJAB5",
        shipname="NORDIC STAR", ship_type=70, to_bow=100, to_stern=20, to_port=10,
        to_starboard=12, epfd=1, month=5, day=14, hour=12, minute=30, draught=7.5,
        destination="HELSINKI",
    )
    lines = vdm(static5, seq_id=3, channel="B")
    assert len(lines) == 2, lines
    messages.append(dict(type=5, lines=lines, expect=dict(
        mmsi=230000005, klass="A", name="NORDIC STAR", call_sign="OJAB5", imo=9123456,
        ship_type=70,
        dimensions=dict(to_bow=100, to_stern=20, to_port=10, to_starboard=12),
    )))

    part_a = dict(type=24, mmsi=230000024, partno=0, shipname="PARTY A")
    messages.append(dict(type="24A", lines=vdm(part_a), expect=dict(
        mmsi=230000024, klass="B", name="PARTY A")))
    part_b = dict(type=24, mmsi=230000024, partno=1, callsign="OH24B", ship_type=36,
                  vendorid="ABC", to_bow=5, to_stern=5, to_port=2, to_starboard=2)
    messages.append(dict(type="24B", lines=vdm(part_b), expect=dict(
        mmsi=230000024, klass="B", call_sign="OH24B", ship_type=36,
        dimensions=dict(to_bow=5, to_stern=5, to_port=2, to_starboard=2))))

    # pyais must read its own sentences back as given (guards this script itself).
    for m in messages:
        decoded = pyais.decode(*m["lines"]).asdict()
        if (decoded["mmsi"] != m["expect"]["mmsi"]
                or decoded["msg_type"] != int(str(m["type"])[:2])):
            sys.exit(f"pyais round trip failed for {m['type']}: {decoded}")

    json.dump(dict(pyais=pyais.__version__, messages=messages), sys.stdout)
    print()


if __name__ == "__main__":
    main()
