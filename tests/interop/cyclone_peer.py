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
      with the frame's stamp; prints `published K STAMP`), `publish K STAMP_NS` the same
      stamped STAMP_NS, `publish K STAMP_NS I` only camera I's image; `quit` (or end of
      input) exits.
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
import os
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
from peer_checks import (  # noqa: E402
    add_peer_commands,
    NANOS,
    POLL_S,
    PeerError,
    dds_topic,
    frames_to_publish,
    say,
    stamp_ns,
    summarize,
    wait_until,
)


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
    for k, stamp, images in frames_to_publish(spec, sys.stdin):
        for image, writer in zip(images, writers):
            if image is None:
                continue
            cam, data = image
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
    add_peer_commands(sub)
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
