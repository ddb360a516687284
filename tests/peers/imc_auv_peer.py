#!/usr/bin/env python3
"""A simulated DUNE AUV speaking IMC through PyPI `imcpy` (LSTS's own DUNE bindings), for
Shoal's IMC proxy tests. Static unicast UDP on 127.0.0.1 only; no multicast discovery.

Behaves like DUNE's UDP transport and plan engine, as far as a CCU can see:
- binds 127.0.0.1:<--port> (0: any free port) and prints {"event": "listening", "port": N};
- waits for the CCU's first packet (Heartbeat/Announce) and from then on sends to the
  address it came from: EstimatedState at 10 Hz (a reference lat/lon plus north/east
  offsets, as DUNE does), FuelLevel, Heartbeat, Announce (sys_type UUV), VehicleState and
  PlanControlState;
- before the first telemetry it sends one packet with a corrupted CRC and one EntityState
  (a real IMC message the proxy does not use), so the proxy's counters can be checked;
- prints {"event": "truth", ...}: the position imcpy's own toWGS84 gives for the first
  EstimatedState, to check the proxy's displacement against DUNE's;
- a PlanControl START with an inline PlanSpecification of Goto maneuvers is printed as
  {"event": "plan", ...}, answered SUCCESS (or FAILURE when a Goto lies more than 5 km
  away) and executed: the vehicle moves --speedup times faster than commanded,
  PlanControlState reports EXECUTING with progress, then READY with outcome SUCCESS;
- Abort stops the plan (outcome FAILURE) and is printed as {"event": "abort"}.
Runs until stdin closes or --lifetime seconds pass.
"""

import argparse
import json
import math
import select
import socket
import sys
import time

import imcpy
import imcpy.coordinates

MAX_GOTO_M = 5000.0


def say(**kw):
    print(json.dumps(kw), flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, default=0)
    ap.add_argument("--imc-id", type=lambda s: int(s, 0), default=0x0017)
    ap.add_argument("--ref-lat", type=float, default=41.185)
    ap.add_argument("--ref-lon", type=float, default=-8.706)
    ap.add_argument("--north", type=float, default=35.0)
    ap.add_argument("--east", type=float, default=-20.0)
    ap.add_argument("--depth", type=float, default=2.0)
    ap.add_argument("--battery", type=float, default=87.5)
    ap.add_argument("--speedup", type=float, default=10.0)
    ap.add_argument("--lifetime", type=float, default=120.0)
    args = ap.parse_args()

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", args.port))
    sock.setblocking(False)
    say(event="listening", port=sock.getsockname()[1])

    ref_lat, ref_lon = math.radians(args.ref_lat), math.radians(args.ref_lon)
    x, y, depth, psi = args.north, args.east, args.depth, 0.0
    ccu = None  # (address, imc id) of the proxy, once heard
    plan = None  # {"id", "gotos": [(n, e, z, speed)], "index", "request"}
    last_outcome = imcpy.PlanControlState.LastPlanOutcomeEnum.NONE
    truth_said = False
    started = time.monotonic()
    tick = 0

    def send(msg):
        if ccu is None:
            return
        msg.src = args.imc_id
        msg.src_ent = 1
        msg.dst = ccu[1]
        msg.dst_ent = 255
        msg.set_timestamp_now()
        sock.sendto(imcpy.Packet.serialize(msg), ccu[0])

    def estimated_state():
        es = imcpy.EstimatedState()
        es.lat, es.lon, es.height = ref_lat, ref_lon, 0.0
        es.x, es.y, es.z = x, y, depth
        es.psi = psi
        es.depth = depth
        es.alt = -1.0
        if plan is not None:
            es.vx = math.cos(psi) * plan["speed"]
            es.vy = math.sin(psi) * plan["speed"]
        return es

    def plan_state():
        pcs = imcpy.PlanControlState()
        if plan is not None:
            pcs.state = imcpy.PlanControlState.StateEnum.EXECUTING
            pcs.plan_id = plan["id"]
            pcs.plan_progress = 100.0 * plan["index"] / len(plan["gotos"])
            pcs.man_id = str(plan["index"] + 1)
        else:
            pcs.state = imcpy.PlanControlState.StateEnum.READY
            pcs.plan_id = last_plan_id
            pcs.plan_progress = 0.0
        pcs.last_outcome = last_outcome
        return pcs

    last_plan_id = ""

    while time.monotonic() - started < args.lifetime:
        readable, _, _ = select.select([sock, sys.stdin], [], [], 0.1)
        if sys.stdin in readable and not sys.stdin.readline():
            break
        while True:
            try:
                data, addr = sock.recvfrom(65535)
            except BlockingIOError:
                break
            try:
                msg = imcpy.Packet.deserialize(data)
            except RuntimeError as e:
                say(event="bad_packet", error=str(e))
                continue
            if ccu is None:
                ccu = (addr, msg.src)
                say(event="ccu", port=addr[1], imc_id=msg.src)
                # Noise first: a corrupted packet and a message the proxy does not use.
                hb = imcpy.Heartbeat()
                hb.src, hb.dst = args.imc_id, msg.src
                bad = bytearray(imcpy.Packet.serialize(hb))
                bad[-1] ^= 0xFF
                sock.sendto(bytes(bad), addr)
                send(imcpy.EntityState())
            elif addr != ccu[0]:
                ccu = (addr, msg.src)
            if isinstance(msg, imcpy.PlanControl) and msg.type == imcpy.PlanControl.TypeEnum.REQUEST:
                if msg.op != imcpy.PlanControl.OperationEnum.START:
                    continue
                spec = msg.arg
                gotos = []
                printed = []
                for pm in spec.maneuvers:
                    g = pm.data
                    n, e, _ = imcpy.coordinates.WGS84.displacement(ref_lat, ref_lon, 0.0, g.lat, g.lon, 0.0)
                    gotos.append((n, e, g.z, g.speed))
                    printed.append({
                        "type": g.msg_name, "id": pm.maneuver_id,
                        "lat_deg": math.degrees(g.lat), "lon_deg": math.degrees(g.lon),
                        "z": g.z, "z_units": int(g.z_units), "speed": g.speed, "speed_units": int(g.speed_units),
                        "timeout": g.timeout,
                    })
                say(event="plan", plan_id=msg.plan_id, request_id=msg.request_id,
                    start=spec.start_man_id, maneuvers=printed,
                    transitions=[(t.source_man, t.dest_man, t.conditions) for t in spec.transitions])
                reply = imcpy.PlanControl()
                reply.op = msg.op
                reply.request_id = msg.request_id
                reply.plan_id = msg.plan_id
                far = [math.hypot(n - x, e - y) for (n, e, _, _) in gotos if math.hypot(n - x, e - y) > MAX_GOTO_M]
                if far or not gotos:
                    reply.type = imcpy.PlanControl.TypeEnum.FAILURE
                    reply.info = "target beyond 5 km" if far else "no maneuvers"
                else:
                    reply.type = imcpy.PlanControl.TypeEnum.SUCCESS
                    plan = {"id": msg.plan_id, "gotos": gotos, "index": 0, "speed": gotos[0][3]}
                    last_plan_id = msg.plan_id
                send(reply)
            elif isinstance(msg, imcpy.Abort):
                say(event="abort", had_plan=plan is not None)
                if plan is not None:
                    last_outcome = imcpy.PlanControlState.LastPlanOutcomeEnum.FAILURE
                    plan = None

        if ccu is None:
            continue
        tick += 1
        dt = 0.1
        if plan is not None:
            n, e, z, speed = plan["gotos"][plan["index"]]
            dn, de = n - x, e - y
            dist = math.hypot(dn, de)
            step = speed * args.speedup * dt
            psi = math.atan2(de, dn)
            depth += max(-step, min(step, z - depth))
            if dist <= step:
                x, y = n, e
                plan["index"] += 1
                if plan["index"] == len(plan["gotos"]):
                    say(event="plan_done", plan_id=plan["id"])
                    last_outcome = imcpy.PlanControlState.LastPlanOutcomeEnum.SUCCESS
                    plan = None
                else:
                    plan["speed"] = plan["gotos"][plan["index"]][3]
            else:
                x += dn / dist * step
                y += de / dist * step
        es = estimated_state()
        send(es)
        if not truth_said:
            lat, lon, _ = imcpy.coordinates.toWGS84(es)
            say(event="truth", lat_deg=math.degrees(lat), lon_deg=math.degrees(lon), depth=depth)
            truth_said = True
        if tick % 2 == 0:
            send(plan_state())
        if tick % 10 == 1:
            send(imcpy.Heartbeat())
            fl = imcpy.FuelLevel()
            fl.value, fl.confidence = args.battery, 90.0
            send(fl)
            vs = imcpy.VehicleState()
            vs.op_mode = (imcpy.VehicleState.OperationModeEnum.MANEUVER if plan is not None
                          else imcpy.VehicleState.OperationModeEnum.SERVICE)
            send(vs)
        if tick % 50 == 1:
            an = imcpy.Announce()
            an.sys_name = "lauv-shoal-sim"
            an.sys_type = imcpy.SystemType.UUV
            an.owner = 0xFFFF
            an.lat, an.lon = ref_lat, ref_lon
            an.services = "imc+udp://127.0.0.1:%d/" % sock.getsockname()[1]
            send(an)


if __name__ == "__main__":
    main()
