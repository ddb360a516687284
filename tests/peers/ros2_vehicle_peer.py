#!/usr/bin/env python3
"""A ROS 2 vehicle as DDS sees it, on PyPI `cyclonedds` (no ROS installed), for Shoal's
ROS 2 proxy tests. Run it inside a loopback-only network namespace, like every DDS test.

It uses exactly what a ROS 2 node on rmw_cyclonedds puts on the wire: topics
rt/<ns>/<name>, type names <pkg>::msg::dds_::<Name>_, the .msg fields in order as
plain CDR (XCDR1), and ROS 2's default QoS (reliable, volatile, keep-last 10):
- publishes sensor_msgs/NavSatFix (fix), nav_msgs/Odometry (odom, z = -depth,
  REP 103 quaternion) and sensor_msgs/BatteryState (battery, percentage as a fraction) at
  10 Hz, and one rcl_interfaces/Log warning on rt/rosout from logger "<ns>.controller";
- subscribes to geometry_msgs/PoseStamped goals (goal_pose), prints each as
  {"event": "goal", ...} and drives there (--speedup times 1 m/s): the goal frame is
  local ENU with its origin at --datum-lat/--datum-lon, z up.
Prints {"event": "ready"} once its endpoints exist. Runs until stdin closes or
--lifetime seconds pass.
"""

import argparse
import json
import math
import select
import sys
import time
from dataclasses import dataclass, field

from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
import cyclonedds.idl.types as t
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

EARTH_A = 6378137.0
EARTH_E2 = 6.69437999014e-3


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: t.int32 = 0
    nanosec: t.uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class NavSatStatus(IdlStruct, typename="sensor_msgs::msg::dds_::NavSatStatus_"):
    status: t.int8 = 0
    service: t.uint16 = 0


@dataclass
class NavSatFix(IdlStruct, typename="sensor_msgs::msg::dds_::NavSatFix_"):
    header: Header = field(default_factory=Header)
    status: NavSatStatus = field(default_factory=NavSatStatus)
    latitude: t.float64 = 0.0
    longitude: t.float64 = 0.0
    altitude: t.float64 = 0.0
    position_covariance: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)
    position_covariance_type: t.uint8 = 0


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0
    w: t.float64 = 1.0


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose = field(default_factory=Pose)
    covariance: t.array[t.float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist = field(default_factory=Twist)
    covariance: t.array[t.float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


@dataclass
class BatteryState(IdlStruct, typename="sensor_msgs::msg::dds_::BatteryState_"):
    header: Header = field(default_factory=Header)
    voltage: t.float32 = 0.0
    temperature: t.float32 = 0.0
    current: t.float32 = 0.0
    charge: t.float32 = 0.0
    capacity: t.float32 = 0.0
    design_capacity: t.float32 = 0.0
    percentage: t.float32 = 0.0
    power_supply_status: t.uint8 = 0
    power_supply_health: t.uint8 = 0
    power_supply_technology: t.uint8 = 0
    present: bool = True
    cell_voltage: t.sequence[t.float32] = field(default_factory=list)
    cell_temperature: t.sequence[t.float32] = field(default_factory=list)
    location: str = ""
    serial_number: str = ""


@dataclass
class PoseStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
    header: Header = field(default_factory=Header)
    pose: Pose = field(default_factory=Pose)


@dataclass
class Log(IdlStruct, typename="rcl_interfaces::msg::dds_::Log_"):
    stamp: Time = field(default_factory=Time)
    level: t.uint8 = 0
    name: str = ""
    msg: str = ""
    file: str = ""
    function: str = ""
    line: t.uint32 = 0


# ROS 2's default QoS for topics; XCDR1 is the plain CDR ROS 2 puts on the wire.
ROS_DEFAULT = Qos(
    Policy.Reliability.Reliable(max_blocking_time=100_000_000),
    Policy.Durability.Volatile,
    Policy.History.KeepLast(10),
    Policy.DataRepresentation(use_cdrv0_representation=True, use_xcdrv2_representation=False),
)


def say(**kw):
    print(json.dumps(kw), flush=True)


def radii(lat_rad):
    s = math.sin(lat_rad)
    w = 1.0 - EARTH_E2 * s * s
    return EARTH_A * (1.0 - EARTH_E2) / (w * math.sqrt(w)), EARTH_A / math.sqrt(w)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--domain", type=int, required=True)
    ap.add_argument("--namespace", default="bluerov")
    ap.add_argument("--datum-lat", type=float, default=59.9)
    ap.add_argument("--datum-lon", type=float, default=10.7)
    ap.add_argument("--east", type=float, default=10.0)
    ap.add_argument("--north", type=float, default=-20.0)
    ap.add_argument("--depth", type=float, default=2.5)
    ap.add_argument("--battery", type=float, default=0.64)
    ap.add_argument("--speedup", type=float, default=10.0)
    ap.add_argument("--lifetime", type=float, default=120.0)
    args = ap.parse_args()

    dp = DomainParticipant(args.domain)

    def topic(name, cls):
        return Topic(dp, "rt/%s/%s" % (args.namespace, name) if args.namespace else "rt/" + name, cls, qos=ROS_DEFAULT)

    fix_w = DataWriter(dp, topic("fix", NavSatFix), qos=ROS_DEFAULT)
    odom_w = DataWriter(dp, topic("odom", Odometry), qos=ROS_DEFAULT)
    bat_w = DataWriter(dp, topic("battery", BatteryState), qos=ROS_DEFAULT)
    log_w = DataWriter(dp, Topic(dp, "rt/rosout", Log, qos=ROS_DEFAULT), qos=ROS_DEFAULT)
    goal_r = DataReader(dp, topic("goal_pose", PoseStamped), qos=ROS_DEFAULT)
    say(event="ready")

    lat0, lon0 = math.radians(args.datum_lat), math.radians(args.datum_lon)
    m_rad, n_rad = radii(lat0)
    east, north, depth, yaw = args.east, args.north, args.depth, 0.0
    goal = None
    started = time.monotonic()
    last, tick, warned = started, 0, False

    while time.monotonic() - started < args.lifetime:
        readable, _, _ = select.select([sys.stdin], [], [], 0)
        if readable and not sys.stdin.readline():
            break
        for g in goal_r.take(N=10):
            if not isinstance(g, PoseStamped):
                continue
            p, q = g.pose.position, g.pose.orientation
            goal = (p.x, p.y, p.z)
            say(event="goal", frame_id=g.header.frame_id, x=p.x, y=p.y, z=p.z,
                qx=q.x, qy=q.y, qz=q.z, qw=q.w, sec=g.header.stamp.sec)
        now = time.monotonic()
        dt = now - last
        if dt < 0.1:
            time.sleep(0.01)
            continue
        last = now
        tick += 1
        speed = 0.0
        if goal is not None:
            gx, gy, gz = goal
            dx, dy = gx - east, gy - north
            dist = math.hypot(dx, dy)
            step = 1.0 * args.speedup * dt
            if dist > 1e-6:
                yaw = math.atan2(dy, dx)
            if dist <= step:
                east, north = gx, gy
            else:
                east += dx / dist * step
                north += dy / dist * step
                speed = 1.0
            depth += max(-step, min(step, -gz - depth))
        stamp = Time(sec=int(time.time()), nanosec=int((time.time() % 1) * 1e9))
        lat = lat0 + north / m_rad
        lon = lon0 + east / (n_rad * math.cos(lat0))
        fix_w.write(NavSatFix(header=Header(stamp=stamp, frame_id="gps"),
                              status=NavSatStatus(status=0, service=1),
                              latitude=math.degrees(lat), longitude=math.degrees(lon),
                              altitude=-depth, position_covariance_type=0))
        odom = Odometry(header=Header(stamp=stamp, frame_id="odom"), child_frame_id="base_link")
        odom.pose.pose.position = Point(x=east, y=north, z=-depth)
        # REP 103: yaw counter-clockwise from east; a small nose-down pitch of 0.1 rad.
        cy, sy, cp, sp = math.cos(yaw / 2), math.sin(yaw / 2), math.cos(0.05), math.sin(0.05)
        odom.pose.pose.orientation = Quaternion(x=-sy * sp, y=cy * sp, z=sy * cp, w=cy * cp)
        odom.twist.twist.linear = Vector3(x=speed, y=0.0, z=0.0)
        odom_w.write(odom)
        if tick % 10 == 1:
            bat_w.write(BatteryState(header=Header(stamp=stamp), voltage=15.8, percentage=args.battery,
                                     present=True, cell_voltage=[3.95, 3.95, 3.95, 3.95]))
        if tick == 20 and not warned:
            warned = True
            log_w.write(Log(stamp=stamp, level=30, name="%s.controller" % args.namespace,
                            msg="thruster 3 current high", file="controller.cpp", function="spin", line=42))
            say(event="warned")


if __name__ == "__main__":
    main()
