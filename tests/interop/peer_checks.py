"""What the DDS peers of the mode360 node's tests (cyclone_peer.py, rclpy_peer.py) share:
the check of a received depth image and point cloud against each other (`summarize`, whose JSON
tests/node/dds_peer.rs asserts on), written from the ROS 2 message definitions and REP 103,
independently of mode360's code, and the line protocol's small helpers. No DDS imports."""

import math
import struct
import time


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


def frames_to_publish(spec, lines):
    """The publishing peers' protocol: for each line `publish K [STAMP_NS [CAMERA]]` of
    `lines` (stdin), yields (K, stamp_ns, images) of frame K of `spec` (frames.json): stamped
    with STAMP_NS instead of the frame's own stamp when given, and only camera index CAMERA's
    image when given (the other entries of `images`, one per camera, are None; each image is
    (camera, rgb8 bytes)); returns on `quit` or at the end of input."""
    width, height = spec["width"], spec["height"]
    for line in lines:
        words = line.split()
        if not words:
            continue
        if words[0] == "quit":
            return
        if words[0] != "publish" or not 2 <= len(words) <= 4:
            raise PeerError(f"unknown command '{line.strip()}'")
        k = int(words[1])
        frame = spec["frames"][k]
        stamp = int(words[2]) if len(words) > 2 else int(frame["stamp_ns"])
        only = int(words[3]) if len(words) > 3 else None
        images = []
        for i, (cam, path) in enumerate(zip(spec["cameras"], frame["files"])):
            if only is not None and i != only:
                images.append(None)
                continue
            with open(path, "rb") as f:
                data = f.read()
            if len(data) != width * height * 3:
                raise PeerError(f"{path}: {len(data)} bytes, expected {width}x{height}x3")
            images.append((cam, data))
        yield k, stamp, images


def add_peer_commands(sub):
    """The `subscribe` and `publish` commands every DDS peer offers (argparse subparsers `sub`)."""
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
