#!/usr/bin/env python3
"""An ArduSub-like vehicle (a BlueROV2 as a GCS sees it) written with PyPI `pymavlink`,
for Shoal's MAVLink proxy tests. MAVLink 2, ardupilotmega dialect, UDP to 127.0.0.1 only.

Like ArduSub behind BlueOS/mavlink-router, it sends to the GCS port (`udpout` to
127.0.0.1:--port) and answers on the same socket:
- HEARTBEAT (MAV_TYPE_SUBMARINE, ArduPilot, armed, custom_mode = the ArduSub mode),
  SYS_STATUS and BATTERY_STATUS at 1 Hz; GLOBAL_POSITION_INT (relative_alt negative
  below the surface), ATTITUDE and VFR_HUD at 10 Hz; one STATUSTEXT warning at start;
- before the first telemetry, one frame with a corrupted CRC and one with a message id
  outside the dialect, so the proxy's counters can be checked;
- COMMAND_LONG DO_SET_MODE (param2: GUIDED 4, AUTO 3, SURFACE 9, POSHOLD 16, MANUAL 19),
  COMPONENT_ARM_DISARM and DO_CHANGE_SPEED are answered with COMMAND_ACK; others are
  UNSUPPORTED;
- SET_POSITION_TARGET_GLOBAL_INT in GUIDED moves the vehicle there; the mission
  protocol (MISSION_COUNT, MISSION_REQUEST_INT per item, MISSION_ACK) loads a mission that
  AUTO runs, with MISSION_CURRENT and MISSION_ITEM_REACHED; SURFACE ascends to 0 m;
- it moves --speedup times faster than commanded, and prints one JSON line per command
  received ({"event": "set_mode" | "position_target" | "mission" | ...}).
Runs until stdin closes or --lifetime seconds pass.
"""

import os

os.environ["MAVLINK20"] = "1"  # pymavlink speaks MAVLink 1 unless told; Shoal wants 2

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import select  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

from pymavlink import mavutil  # noqa: E402

GUIDED, AUTO, SURFACE, POSHOLD, MANUAL = 4, 3, 9, 16, 19
MODES = {0, 1, 2, AUTO, GUIDED, 7, SURFACE, POSHOLD, MANUAL}
EARTH_R = 6_371_000.0


def say(**kw):
    print(json.dumps(kw), flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--lat", type=float, default=47.397742)
    ap.add_argument("--lon", type=float, default=8.545594)
    ap.add_argument("--depth", type=float, default=3.0)
    ap.add_argument("--battery", type=int, default=76)
    ap.add_argument("--speedup", type=float, default=10.0)
    ap.add_argument("--lifetime", type=float, default=120.0)
    args = ap.parse_args()

    m = mavutil.mavlink_connection(
        "udpout:127.0.0.1:%d" % args.port, source_system=1, source_component=1,
        dialect="ardupilotmega")
    mav = m.mav
    assert mavutil.mavlink.WIRE_PROTOCOL_VERSION == "2.0", "MAVLink 2 is required"
    say(event="started", mavlink=mavutil.mavlink.WIRE_PROTOCOL_VERSION)

    lat, lon, depth = args.lat, args.lon, args.depth
    yaw, speed = 0.0, 0.5
    mode, armed = MANUAL, True
    target = None  # (lat, lon, depth) in GUIDED
    mission, upload = [], None  # items; {"count", "items"} while uploading
    mission_seq = 0
    gcs_seen = False
    started = time.monotonic()
    last_slow, last_fast = 0.0, 0.0

    # Noise first: a frame with a broken CRC and one with an id outside the dialect.
    hb = mavutil.mavlink.MAVLink_heartbeat_message(
        mavutil.mavlink.MAV_TYPE_SUBMARINE, mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0, 3)
    bad = bytearray(hb.pack(mav))
    bad[-1] ^= 0xFF
    m.write(bytes(bad))
    m.write(bytes([0xFD, 2, 0, 0, 0, 1, 1, 0x33, 0xEA, 0x00, 0xAB, 0xCD, 0x12, 0x34]))

    def move_towards(tlat, tlon, tdepth, dt):
        nonlocal lat, lon, depth, yaw
        step = speed * args.speedup * dt
        dn = math.radians(tlat - lat) * EARTH_R
        de = math.radians(tlon - lon) * EARTH_R * math.cos(math.radians(lat))
        dist = math.hypot(dn, de)
        if dist <= step:
            lat, lon = tlat, tlon
        else:
            yaw = math.atan2(de, dn)
            lat += math.degrees(dn / dist * step / EARTH_R)
            lon += math.degrees(de / dist * step / (EARTH_R * math.cos(math.radians(lat))))
        depth += max(-step, min(step, tdepth - depth))
        return dist <= step and abs(tdepth - depth) < 0.05

    def nav_item(seq):
        it = mission[seq]
        return it.command == mavutil.mavlink.MAV_CMD_NAV_WAYPOINT

    while time.monotonic() - started < args.lifetime:
        readable, _, _ = select.select([sys.stdin], [], [], 0)
        if readable and not sys.stdin.readline():
            break
        msg = m.recv_match(blocking=True, timeout=0.02)
        while msg is not None:
            t = msg.get_type()
            src = msg.get_srcSystem()
            if t == "BAD_DATA":
                pass
            elif t == "HEARTBEAT" and src == 255 and not gcs_seen:
                gcs_seen = True
                say(event="gcs_heartbeat", type=msg.type, mavlink2=msg.get_msgbuf()[0] == 0xFD)
            elif t == "REQUEST_DATA_STREAM":
                say(event="request_data_stream", rate=msg.req_message_rate, stream=msg.req_stream_id)
            elif t == "COMMAND_LONG":
                result = mavutil.mavlink.MAV_RESULT_ACCEPTED
                if msg.command == mavutil.mavlink.MAV_CMD_DO_SET_MODE:
                    new = int(msg.param2)
                    say(event="set_mode", mode=new, param1=msg.param1)
                    if new in MODES:
                        mode = new
                        if mode == AUTO:
                            mission_seq = 1
                    else:
                        result = mavutil.mavlink.MAV_RESULT_DENIED
                elif msg.command == mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
                    armed = msg.param1 == 1
                    say(event="arm", armed=armed)
                elif msg.command == mavutil.mavlink.MAV_CMD_DO_CHANGE_SPEED:
                    speed = msg.param2
                    say(event="change_speed", speed=speed)
                else:
                    result = mavutil.mavlink.MAV_RESULT_UNSUPPORTED
                mav.command_ack_send(msg.command, result)
            elif t == "SET_POSITION_TARGET_GLOBAL_INT":
                say(event="position_target", lat_int=msg.lat_int, lon_int=msg.lon_int, alt=msg.alt,
                    frame=msg.coordinate_frame, type_mask=msg.type_mask, mode=mode,
                    target=[msg.target_system, msg.target_component])
                if mode == GUIDED:
                    target = (msg.lat_int / 1e7, msg.lon_int / 1e7, -msg.alt)
            elif t == "MISSION_COUNT":
                upload = {"count": msg.count, "items": []}
                mav.mission_request_int_send(src, msg.get_srcComponent(), 0)
            elif t == "MISSION_ITEM_INT" and upload is not None:
                if msg.seq == len(upload["items"]):
                    upload["items"].append(msg)
                if len(upload["items"]) < upload["count"]:
                    mav.mission_request_int_send(src, msg.get_srcComponent(), len(upload["items"]))
                else:
                    mission = upload["items"]
                    upload = None
                    mav.mission_ack_send(src, msg.get_srcComponent(), mavutil.mavlink.MAV_MISSION_ACCEPTED)
                    say(event="mission", items=[{
                        "seq": it.seq, "command": it.command, "frame": it.frame,
                        "lat_deg": it.x / 1e7, "lon_deg": it.y / 1e7, "z": it.z,
                        "param1": it.param1, "param2": it.param2} for it in mission])
            msg = m.recv_match(blocking=False)

        now = time.monotonic()
        dt = now - last_fast
        if dt < 0.1:
            continue
        last_fast = now
        if mode == GUIDED and target is not None and armed:
            move_towards(*target, dt)
        elif mode == AUTO and mission and mission_seq < len(mission):
            while mission_seq < len(mission) and not nav_item(mission_seq):
                it = mission[mission_seq]
                if it.command == mavutil.mavlink.MAV_CMD_DO_CHANGE_SPEED:
                    speed = it.param2
                mission_seq += 1
            if mission_seq < len(mission):
                it = mission[mission_seq]
                if move_towards(it.x / 1e7, it.y / 1e7, -it.z, dt):
                    mav.mission_item_reached_send(mission_seq)
                    say(event="item_reached", seq=mission_seq)
                    mission_seq += 1
                    if mission_seq < len(mission):
                        mav.mission_current_send(mission_seq)
        elif mode == SURFACE:
            depth = max(0.0, depth - 0.5 * args.speedup * dt)

        boot_ms = int((now - started) * 1000)
        vn = vn_e = 0.0
        if (mode == GUIDED and target) or (mode == AUTO and mission):
            vn, vn_e = math.cos(yaw) * speed, math.sin(yaw) * speed
        mav.global_position_int_send(
            boot_ms, int(round(lat * 1e7)), int(round(lon * 1e7)), int(-depth * 1000),
            int(round(-depth * 1000)), int(vn * 100), int(vn_e * 100), 0,
            int(math.degrees(yaw) % 360 * 100))
        mav.attitude_send(boot_ms, 0.02, -0.05, yaw, 0.0, 0.0, 0.0)
        mav.vfr_hud_send(0.0, math.hypot(vn, vn_e), int(math.degrees(yaw) % 360), 0, -depth, 0.0)

        if now - last_slow >= 1.0:
            if last_slow == 0.0:
                mav.statustext_send(mavutil.mavlink.MAV_SEVERITY_WARNING, b"Shoal peer: leak sensor self-test")
            last_slow = now
            base = mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            if armed:
                base |= mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED
            mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_SUBMARINE, mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                               base, mode, mavutil.mavlink.MAV_STATE_ACTIVE)
            mav.sys_status_send(0, 0, 0, 200, 15800, 1200, args.battery, 0, 0, 0, 0, 0, 0)
            mav.battery_status_send(0, mavutil.mavlink.MAV_BATTERY_FUNCTION_ALL, mavutil.mavlink.MAV_BATTERY_TYPE_LION,
                                    2500, [15800] + [65535] * 9, 1200, 500, 100, args.battery)
            if mode == AUTO and mission:
                mav.mission_current_send(min(mission_seq, len(mission) - 1))


if __name__ == "__main__":
    main()
