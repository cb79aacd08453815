#!/usr/bin/env python3
"""A real ROS 2 client as a peer of the mode360 node, used by tests/node/rclpy.rs: rclpy with
rmw_fastrtps_cpp and Fast DDS's default settings (its default socket buffers, shared memory
and UDP), from the `ros-<distro>-rclpy` wheels that tests/interop/setup.sh installs. Message
types are rclpy's own (sensor_msgs, rcl_interfaces); discovery stays on this host
(ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST).

  rclpy_peer.py subscribe --domain D [--depth-topic /depth] [--points-topic /points]
                          [--max-depth-m 1000] [--timeout-s 30]
      As cyclone_peer.py subscribe: `ready` once both subscriptions see a publisher, then
      `result {json}` (peer_checks.summarize) of the first depth image and cloud with one stamp.

  rclpy_peer.py publish --domain D --frames frames.json [--timeout-s 30]
      As cyclone_peer.py publish: rclpy as the camera driver (sensor-data QoS), including
      `publish K STAMP_NS [I]` (another stamp; one camera only): the time-jump test drives
      poisoned stamps, a clock reset, a looped sequence and a flooding camera with it.

  rclpy_peer.py stream --domain D [--timeout-s 120] [--best-effort]
      Reliable subscriptions with rclpy's defaults (reliable, volatile, keep last 10: what
      rviz and `ros2 topic echo` use), or with --best-effort rclpy's sensor-data QoS (best
      effort, keep last 5), to /depth, /confidence and /points; `ready` once each
      sees a publisher; on stdin `quit` (or end of input) prints `result {json}`: per topic
      the [stamp_ns, receive_ns] of every message received (receive_ns: wall clock).

  rclpy_peer.py params --domain D --node /mode360 --set NAME=VALUE --refused NAME=VALUE
                       --describe A,B,C [--names-per-call 8]
      The parameter services as `ros2 param` uses them: list, get every listed one (all in
      one request, as `ros2 param dump` asks, or --names-per-call at a time), describe A, B
      and C (`--describe all`: every listed one in one request), set NAME (must succeed),
      set the other (must be refused); prints `result {json}`.

  rclpy_peer.py types --domain D --node /mode360 [--timeout-s 30]
      The graph as `ros2 topic info -v` reads it: once the node's topics and services have
      held still for a second, for each of its publishers, subscriptions and service
      endpoints (`rq/<service>Request`, `rr/<service>Reply`) the type and the type hash its
      discovery announced, beside the hash rosidl generated for that type in this
      distribution (`share/<pkg>/{msg,srv}/<Type>.json`; null where rclpy lacks the package);
      prints `result {"endpoints": [...]}`.

Exit status 0 on success; 1 with a message on stderr when something is missing or malformed;
2 on bad usage.
"""

import argparse
import json
import os
import sys
import threading
import time

from peer_checks import add_peer_commands, NANOS, POLL_S, PeerError, frames_to_publish, say, stamp_ns, summarize, wait_until


def start(domain):
    """rclpy on `domain`, this host only; returns the rclpy module and a node."""
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    import rclpy

    rclpy.init()
    return rclpy, rclpy.create_node("mode360_rclpy_peer")


def spin_until(rclpy, node, predicate, timeout_s, what):
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise PeerError(f"timed out after {timeout_s} s waiting for {what}")
        rclpy.spin_once(node, timeout_sec=POLL_S)


def subscribe(args):
    from sensor_msgs.msg import Image, PointCloud2

    rclpy, node = start(args.domain)
    depths, clouds = {}, {}
    node.create_subscription(Image, args.depth_topic, lambda m: depths.setdefault(stamp_ns(m.header), m), 10)
    node.create_subscription(
        PointCloud2, args.points_topic, lambda m: clouds.setdefault(stamp_ns(m.header), m), 10
    )
    spin_until(
        rclpy,
        node,
        lambda: node.count_publishers(args.depth_topic) and node.count_publishers(args.points_topic),
        args.timeout_s,
        f"publishers of {args.depth_topic} and {args.points_topic}",
    )
    say("ready")
    spin_until(rclpy, node, lambda: set(depths) & set(clouds), args.timeout_s, "a depth image and cloud of one stamp")
    stamp = sorted(set(depths) & set(clouds))[0]
    result = summarize(depths[stamp], clouds[stamp], args.max_depth_m)
    result["received"] = {"depth": len(depths), "points": len(clouds)}
    say("result " + json.dumps(result))


def publish(args):
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Image

    with open(args.frames, encoding="utf-8") as f:
        spec = json.load(f)
    width, height = spec["width"], spec["height"]
    cameras = spec["cameras"]
    rclpy, node = start(args.domain)
    qos = qos_profile_sensor_data
    writers = [node.create_publisher(Image, c["topic"], qos) for c in cameras]
    spin_until(
        rclpy,
        node,
        lambda: all(w.get_subscription_count() for w in writers),
        args.timeout_s,
        "subscribers of " + ", ".join(c["topic"] for c in cameras),
    )
    say("ready")
    for k, stamp, images in frames_to_publish(spec, sys.stdin):
        for image, writer in zip(images, writers):
            if image is None:
                continue
            cam, data = image
            msg = Image()
            msg.header.stamp.sec = stamp // NANOS
            msg.header.stamp.nanosec = stamp % NANOS
            msg.header.frame_id = cam["frame_id"]
            msg.height, msg.width = height, width
            msg.encoding, msg.is_bigendian, msg.step = "rgb8", 0, width * 3
            msg.data = data
            writer.publish(msg)
        say(f"published {k} {stamp}")


def stream(args):
    from sensor_msgs.msg import Image, PointCloud2

    rclpy, node = start(args.domain)
    topics = {"/depth": Image, "/confidence": Image, "/points": PointCloud2}
    got = {t: [] for t in topics}
    if args.best_effort:
        from rclpy.qos import qos_profile_sensor_data as qos
    else:
        qos = 10
    for topic, kind in topics.items():
        node.create_subscription(
            kind, topic, lambda m, t=topic: got[t].append([str(stamp_ns(m.header)), str(time.time_ns())]), qos
        )
    spin_until(
        rclpy, node, lambda: all(node.count_publishers(t) for t in topics), args.timeout_s, "publishers of " + ", ".join(topics)
    )
    say("ready")
    done = threading.Event()

    def wait_for_quit():
        for line in sys.stdin:
            if line.strip() == "quit":
                break
        done.set()

    threading.Thread(target=wait_for_quit, daemon=True).start()
    deadline = time.monotonic() + args.timeout_s
    while not done.is_set() and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=POLL_S)
    say("result " + json.dumps(got))


def params(args):
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters

    rclpy, node = start(args.domain)

    def call(kind, service, request):
        client = node.create_client(kind, f"{args.node}/{service}")
        wait_until(lambda: client.wait_for_service(timeout_sec=0.1), args.timeout_s, f"{args.node}/{service}")
        future = client.call_async(request)
        spin_until(rclpy, node, future.done, args.timeout_s, f"{service}'s answer")
        return future.result()

    def value_of(v):
        return {
            ParameterType.PARAMETER_BOOL: lambda: v.bool_value,
            ParameterType.PARAMETER_INTEGER: lambda: v.integer_value,
            ParameterType.PARAMETER_DOUBLE: lambda: v.double_value,
            ParameterType.PARAMETER_STRING: lambda: v.string_value,
        }.get(v.type, lambda: None)()

    def parameter(assignment):
        name, text = assignment.split("=", 1)
        value = ParameterValue()
        for kind, field, parse in (
            (ParameterType.PARAMETER_INTEGER, "integer_value", int),
            (ParameterType.PARAMETER_DOUBLE, "double_value", float),
        ):
            try:
                setattr(value, field, parse(text))
                value.type = kind
                break
            except ValueError:
                continue
        else:
            if text in ("true", "false"):
                value.type, value.bool_value = ParameterType.PARAMETER_BOOL, text == "true"
            else:
                value.type, value.string_value = ParameterType.PARAMETER_STRING, text
        return Parameter(name=name, value=value)

    names = list(call(ListParameters, "list_parameters", ListParameters.Request()).result.names)
    # All names in one request by default, as `ros2 param dump` asks (the reply is several
    # kB: more than one datagram behind this host's MTU).
    per_call = args.names_per_call or len(names)
    got = []
    for i in range(0, len(names), per_call):
        chunk = names[i : i + per_call]
        got += call(GetParameters, "get_parameters", GetParameters.Request(names=chunk)).values
    to_describe = names if args.describe == "all" else args.describe.split(",")
    described = call(
        DescribeParameters, "describe_parameters", DescribeParameters.Request(names=to_describe)
    ).descriptors
    results = {}
    for key, assignment in (("set", args.set), ("refused", args.refused)):
        p = parameter(assignment)
        r = call(SetParameters, "set_parameters", SetParameters.Request(parameters=[p])).results[0]
        results[key] = {"name": p.name, "successful": r.successful, "reason": r.reason}
    after = call(GetParameters, "get_parameters", GetParameters.Request(names=[results["set"]["name"]])).values
    say(
        "result "
        + json.dumps(
            {
                "names": names,
                "values": {n: value_of(v) for n, v in zip(names, got)},
                "types": {d.name: d.type for d in described},
                "described": [
                    {
                        "name": d.name,
                        "read_only": d.read_only,
                        "description": d.description,
                        "ranges": [[r.from_value, r.to_value] for r in d.floating_point_range]
                        + [[r.from_value, r.to_value] for r in d.integer_range],
                    }
                    for d in described
                ],
                "set": results["set"],
                "refused": results["refused"],
                "after_set": value_of(after[0]),
            }
        )
    )


def rosidl_type_hash(type_name):
    """The hash rosidl generated for `pkg/msg/T` or `pkg/srv/S_Request` (or DDS's
    `pkg::srv::dds_::S_Request_`), or None where this distribution lacks the package."""
    if "::dds_::" in type_name:
        type_name = type_name.replace("::dds_::", "/").replace("::", "/").removesuffix("_")
    package, kind, name = type_name.split("/")
    file_name = name
    if kind == "srv":
        file_name = name.removesuffix("_Request").removesuffix("_Response")
    # The wheels install every package's share/ under the venv (no AMENT_PREFIX_PATH).
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    shares = [os.path.join(p, "share", package) for p in prefixes + [sys.prefix]]
    share = next((d for d in shares if os.path.isdir(d)), None)
    if share is None:
        return None
    with open(os.path.join(share, kind, file_name + ".json")) as f:
        hashes = json.load(f)["type_hashes"]
    return next(h["hash_string"] for h in hashes if h["type_name"] == type_name)


def types(args):
    rclpy, node = start(args.domain)
    ns, _, name = args.node.rpartition("/")
    ns = ns or "/"

    def graph():
        try:
            return (
                sorted(node.get_publisher_names_and_types_by_node(name, ns)),
                sorted(node.get_subscriber_names_and_types_by_node(name, ns)),
                sorted(node.get_service_names_and_types_by_node(name, ns)),
            )
        except Exception:  # the node is not discovered yet
            return None

    # Discovery announces endpoints one by one: wait until the node's graph holds still.
    deadline = time.monotonic() + args.timeout_s
    last, stable_since = None, time.monotonic()
    while True:
        rclpy.spin_once(node, timeout_sec=POLL_S)
        now = graph()
        if now != last:
            last, stable_since = now, time.monotonic()
        elif now and now[0] and now[2] and time.monotonic() - stable_since > 1.0:
            break
        if time.monotonic() > deadline:
            raise PeerError(f"timed out after {args.timeout_s} s waiting for {args.node}'s graph")
    publishers, subscriptions, services = last

    endpoints = []

    def add(kind, topic, infos):
        for info in infos:
            if info.node_name != name or info.node_namespace != ns:
                continue
            endpoints.append(
                {
                    "kind": kind,
                    "topic": topic,
                    "type": info.topic_type,
                    "hash": str(info.topic_type_hash),
                    "expected": rosidl_type_hash(info.topic_type),
                }
            )

    for topic, _ in publishers:
        add("publisher", topic, node.get_publishers_info_by_topic(topic))
    for topic, _ in subscriptions:
        add("subscription", topic, node.get_subscriptions_info_by_topic(topic))
    for service, _ in services:
        request, reply = f"rq{service}Request", f"rr{service}Reply"
        add("service request", request, node.get_subscriptions_info_by_topic(request, no_mangle=True))
        add("service reply", reply, node.get_publishers_info_by_topic(reply, no_mangle=True))
    say("result " + json.dumps({"endpoints": endpoints}))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    add_peer_commands(sub)
    st = sub.add_parser("stream")
    st.add_argument("--domain", type=int, required=True)
    st.add_argument("--timeout-s", type=float, default=120.0)
    st.add_argument("--best-effort", action="store_true", help="sensor-data QoS instead of reliable")
    pa = sub.add_parser("params")
    pa.add_argument("--domain", type=int, required=True)
    pa.add_argument("--node", default="/mode360")
    pa.add_argument("--set", required=True)
    pa.add_argument("--refused", required=True)
    pa.add_argument("--describe", required=True, help="comma-separated names, or all")
    pa.add_argument("--names-per-call", type=int, default=0, help="names in one get_parameters request (0: all)")
    pa.add_argument("--timeout-s", type=float, default=30.0)
    ty = sub.add_parser("types")
    ty.add_argument("--domain", type=int, required=True)
    ty.add_argument("--node", default="/mode360")
    ty.add_argument("--timeout-s", type=float, default=30.0)
    args = parser.parse_args()
    commands = {"subscribe": subscribe, "publish": publish, "stream": stream, "params": params, "types": types}
    try:
        commands[args.command](args)
    except PeerError as e:
        print(f"rclpy_peer {args.command}: {e}", file=sys.stderr, flush=True)
        sys.exit(1)


if __name__ == "__main__":
    main()
