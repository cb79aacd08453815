#!/usr/bin/env python3
"""A Cyclone DDS peer of the mode360 node, used by tests/node/cyclone.rs.

Types are declared here from the ROS 2 .msg definitions (rosidl's DDS names:
`sensor_msgs::msg::dds_::Image_`, topics `rt/<name>`), independently of mode360's code.
Discovery and data stay on the loopback interface.

  cyclone_peer.py subscribe --domain D [--depth-topic /depth] [--points-topic /points]
                            [--max-depth-m 1000] [--timeout-s 30]
      Prints `ready` once both readers are matched with a writer, then waits for a `depth`
      image and a `points` cloud with the same stamp, checks them against each other and
      prints `result {json}` (see `summarize`). QoS as the node's outputs: reliable,
      volatile, keep last.

  cyclone_peer.py publish --domain D --frames frames.json [--timeout-s 30]
      frames.json: {"width", "height", "cameras": [{"topic", "frame_id"}],
      "frames": [{"stamp_ns", "files": [raw rgb8 file per camera]}]}.
      Prints `ready` once every camera writer is matched with a reader, then obeys stdin
      lines: `publish K` sends frame K on every camera topic (rgb8 sensor_msgs/Image, all
      with the frame's stamp; prints `published K STAMP`), `quit` (or end of input) exits.
      QoS as the node's camera subscriptions (sensor data): best effort, volatile, keep last 5.

  cyclone_peer.py rosout --domain D [--timeout-s 60]
      Prints `ready` once its reader exists, then every rcl_interfaces/msg/Log record on
      /rosout as one JSON line (level, name, msg, file, function, line, stamp_ns) until the
      timeout. QoS as rcl's /rosout: reliable, transient local.

Exit status 0 on success; 1 with a message on stderr when something is missing or malformed;
2 on bad usage.
"""

import argparse
import json
import math
import os
import struct
import sys
import time
from dataclasses import dataclass

# Loopback only; SPDP by multicast on lo plus unicast to local peers, data by unicast.
os.environ["CYCLONEDDS_URI"] = (
    "<CycloneDDS><Domain id='any'><General><Interfaces>"
    "<NetworkInterface address='127.0.0.1' multicast='true'/>"
    "</Interfaces><AllowMulticast>spdp</AllowMulticast></General>"
    "<Discovery><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>"
    "<Peers><Peer address='127.0.0.1'/></Peers></Discovery></Domain></CycloneDDS>"
)

from cyclonedds.core import ReadCondition, SampleState, InstanceState, ViewState, WaitSet  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.idl import IdlStruct  # noqa: E402
from cyclonedds.idl.types import int32, sequence, uint8, uint32  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.qos import Policy, Qos  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402
from cyclonedds.util import duration  # noqa: E402


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class Image(IdlStruct, typename="sensor_msgs::msg::dds_::Image_"):
    header: Header
    height: uint32
    width: uint32
    encoding: str
    is_bigendian: uint8
    step: uint32
    data: sequence[uint8]


@dataclass
class PointField(IdlStruct, typename="sensor_msgs::msg::dds_::PointField_"):
    name: str
    offset: uint32
    datatype: uint8
    count: uint32


@dataclass
class PointCloud2(IdlStruct, typename="sensor_msgs::msg::dds_::PointCloud2_"):
    header: Header
    height: uint32
    width: uint32
    fields: sequence[PointField]
    is_bigendian: bool
    point_step: uint32
    row_step: uint32
    data: sequence[uint8]
    is_dense: bool


@dataclass
class Log(IdlStruct, typename="rcl_interfaces::msg::dds_::Log_"):
    stamp: Time
    level: uint8
    name: str
    msg: str
    file: str
    function: str
    line: uint32


FLOAT32 = 7  # sensor_msgs/PointField datatype
POLL_S = 0.02
NANOS = 1_000_000_000


class PeerError(Exception):
    pass


def dds_topic(name):
    """ROS 2 topic `/a/b` as its DDS topic `rt/a/b`."""
    if not name.startswith("/"):
        raise PeerError(f"topic '{name}' must be absolute (start with '/')")
    return "rt" + name


def stamp_ns(header):
    return header.stamp.sec * NANOS + header.stamp.nanosec


def fnv1a64(data):
    h = 0xCBF29CE484222325
    for b in data:
        h = ((h ^ b) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return f"{h:016x}"


def erp_direction(u, v, width, height):
    """Ray of pixel (u, v) of a width x height equirectangular image (REP 103 axes:
    longitude 0 at the centre column, +pi/2 is +y; the top row looks up)."""
    lon = math.pi * (1.0 - 2.0 * (u + 0.5) / width)
    lat = math.pi / 2.0 - math.pi * (v + 0.5) / height
    return (
        math.cos(lat) * math.cos(lon),
        math.cos(lat) * math.sin(lon),
        math.sin(lat),
    )


def is_point_range(r, max_depth_m):
    return math.isfinite(r) and 0.0 < r < max_depth_m


def say(line):
    print(line, flush=True)


def wait_until(predicate, timeout_s, what):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise PeerError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(POLL_S)


def summarize(depth, cloud, max_depth_m):
    """What the Rust test asserts on: the depth image's header and size, its finite and
    point-worthy ranges, and the cloud's layout, count and x y z against range x direction."""
    if depth.encoding != "32FC1":
        raise PeerError(f"depth: encoding '{depth.encoding}', expected '32FC1'")
    w, h, step = depth.width, depth.height, depth.step
    data = bytes(depth.data)
    if step < 4 * w or len(data) != h * step:
        raise PeerError(
            f"depth: {len(data)} bytes for {w}x{h} with step {step} (need {h * step}, step >= {4 * w})"
        )
    fmt = ">f" if depth.is_bigendian else "<f"
    ranges = [
        (u, v, struct.unpack_from(fmt, data, v * step + 4 * u)[0])
        for v in range(h)
        for u in range(w)
    ]
    finite = sum(1 for (_, _, r) in ranges if math.isfinite(r))
    wanted = [(u, v, r) for (u, v, r) in ranges if is_point_range(r, max_depth_m)]

    fields = {f.name: (f.offset, f.datatype, f.count) for f in cloud.fields}
    for name in ("x", "y", "z"):
        if fields.get(name, (None, None, None))[1:] != (FLOAT32, 1):
            raise PeerError(f"points: field '{name}' missing or not one float32: {fields}")
    cdata = bytes(cloud.data)
    n_points = cloud.width * cloud.height
    if len(cdata) != n_points * cloud.point_step:
        raise PeerError(
            f"points: {len(cdata)} bytes for {n_points} points of {cloud.point_step} bytes"
        )
    pfmt = ">f" if cloud.is_bigendian else "<f"
    max_err = 0.0
    checked = 0
    # The node writes one point per point-worthy pixel, row by row.
    for k, (u, v, r) in enumerate(wanted[:n_points]):
        d = erp_direction(u, v, w, h)
        base = k * cloud.point_step
        for axis, name in enumerate(("x", "y", "z")):
            got = struct.unpack_from(pfmt, cdata, base + fields[name][0])[0]
            max_err = max(max_err, abs(got - r * d[axis]))
        checked += 1
    return {
        "depth": {
            "stamp_ns": str(stamp_ns(depth.header)),
            "frame_id": depth.header.frame_id,
            "width": w,
            "height": h,
            "encoding": depth.encoding,
            "step": step,
            "finite_ranges": finite,
            "point_ranges": len(wanted),
            "fnv1a64": fnv1a64(data),
        },
        "points": {
            "stamp_ns": str(stamp_ns(cloud.header)),
            "frame_id": cloud.header.frame_id,
            "width": cloud.width,
            "height": cloud.height,
            "point_step": cloud.point_step,
            "fields": [[f.name, f.offset, f.datatype, f.count] for f in cloud.fields],
            "is_dense": bool(cloud.is_dense),
            "checked_points": checked,
            "max_xyz_error_m": max_err,
            "fnv1a64": fnv1a64(cdata),
        },
    }


def subscribe(args):
    dp = DomainParticipant(args.domain)
    qos = Qos(
        Policy.Reliability.Reliable(duration(seconds=1)),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(10),
    )
    depth_reader = DataReader(dp, Topic(dp, dds_topic(args.depth_topic), Image), qos=qos)
    points_reader = DataReader(dp, Topic(dp, dds_topic(args.points_topic), PointCloud2), qos=qos)
    wait_until(
        lambda: depth_reader.get_matched_publications() and points_reader.get_matched_publications(),
        args.timeout_s,
        f"writers of {args.depth_topic} and {args.points_topic}",
    )
    say("ready")
    waitset = WaitSet(dp)
    mask = SampleState.NotRead | ViewState.Any | InstanceState.Any
    conditions = [ReadCondition(depth_reader, mask), ReadCondition(points_reader, mask)]
    for c in conditions:
        waitset.attach(c)
    depths, clouds = {}, {}
    deadline = time.monotonic() + args.timeout_s
    while True:
        for sample in depth_reader.take(N=100):
            depths[stamp_ns(sample.header)] = sample
        for sample in points_reader.take(N=100):
            clouds[stamp_ns(sample.header)] = sample
        common = sorted(set(depths) & set(clouds))
        if common:
            stamp = common[0]
            result = summarize(depths[stamp], clouds[stamp], args.max_depth_m)
            result["received"] = {"depth": len(depths), "points": len(clouds)}
            say("result " + json.dumps(result))
            return
        left = deadline - time.monotonic()
        if left <= 0:
            raise PeerError(
                f"timed out after {args.timeout_s} s: {len(depths)} depth and "
                f"{len(clouds)} points received, none with a common stamp"
            )
        waitset.wait(int(min(left, 1.0) * NANOS))


def publish(args):
    with open(args.frames, encoding="utf-8") as f:
        spec = json.load(f)
    width, height = spec["width"], spec["height"]
    cameras = spec["cameras"]
    frames = spec["frames"]
    dp = DomainParticipant(args.domain)
    qos = Qos(
        Policy.Reliability.BestEffort,
        Policy.Durability.Volatile,
        Policy.History.KeepLast(5),
    )
    writers = [DataWriter(dp, Topic(dp, dds_topic(c["topic"]), Image), qos=qos) for c in cameras]
    wait_until(
        lambda: all(w.get_matched_subscriptions() for w in writers),
        args.timeout_s,
        "readers of " + ", ".join(c["topic"] for c in cameras),
    )
    say("ready")
    for line in sys.stdin:
        words = line.split()
        if not words:
            continue
        if words[0] == "quit":
            return
        if words[0] != "publish" or len(words) != 2:
            raise PeerError(f"unknown command '{line.strip()}'")
        k = int(words[1])
        frame = frames[k]
        stamp = int(frame["stamp_ns"])
        for cam, writer, path in zip(cameras, writers, frame["files"]):
            with open(path, "rb") as f:
                data = f.read()
            if len(data) != width * height * 3:
                raise PeerError(f"{path}: {len(data)} bytes, expected {width}x{height}x3")
            writer.write(
                Image(
                    header=Header(
                        stamp=Time(sec=stamp // NANOS, nanosec=stamp % NANOS),
                        frame_id=cam["frame_id"],
                    ),
                    height=height,
                    width=width,
                    encoding="rgb8",
                    is_bigendian=0,
                    step=width * 3,
                    data=list(data),
                )
            )
        say(f"published {k} {stamp}")


def rosout(args):
    """Prints every rcl_interfaces/msg/Log record on /rosout as one JSON line ("ready" first),
    until stdin closes or the timeout passes."""
    dp = DomainParticipant(args.domain)
    topic = Topic(dp, dds_topic("/rosout"), Log)
    qos = Qos(
        Policy.Reliability.Reliable(duration(seconds=1)),
        Policy.Durability.TransientLocal,
        Policy.History.KeepLast(100),
    )
    reader = DataReader(dp, topic, qos=qos)
    say("ready")
    deadline = time.monotonic() + args.timeout_s
    while time.monotonic() < deadline:
        for r in reader.take(N=100):
            say(json.dumps({"level": r.level, "name": r.name, "msg": r.msg, "file": r.file,
                            "function": r.function, "line": r.line,
                            "stamp_ns": r.stamp.sec * NANOS + r.stamp.nanosec}))
        time.sleep(POLL_S)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    s = sub.add_parser("subscribe")
    s.add_argument("--domain", type=int, required=True)
    s.add_argument("--depth-topic", default="/depth")
    s.add_argument("--points-topic", default="/points")
    s.add_argument("--max-depth-m", type=float, default=1000.0)
    s.add_argument("--timeout-s", type=float, default=30.0)
    p = sub.add_parser("publish")
    p.add_argument("--domain", type=int, required=True)
    p.add_argument("--frames", required=True)
    p.add_argument("--timeout-s", type=float, default=30.0)
    r = sub.add_parser("rosout")
    r.add_argument("--domain", type=int, required=True)
    r.add_argument("--timeout-s", type=float, default=60.0)
    args = parser.parse_args()
    try:
        {"subscribe": subscribe, "publish": publish, "rosout": rosout}[args.command](args)
    except PeerError as e:
        print(f"cyclone_peer {args.command}: {e}", file=sys.stderr, flush=True)
        sys.exit(1)


if __name__ == "__main__":
    main()
