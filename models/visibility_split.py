#!/usr/bin/env python3
"""δ1 of a replayed bag split by how many cameras see each ground-truth point.

Where a depth estimate fails on a point that one camera alone sees, no matching could have
found it; where all the cameras see it, the evidence was there. This script tells the two apart
for an equirectangular rig whose cameras are not rotated (such as launch_configs/rig_deep360.yaml).

Camera k sees the reference camera's ground-truth point X when its own ground truth (the same
world rendered with camera k as the reference) along the direction from k to X lies within
SEEN_TOLERANCE of |X - o_k| at one of the 3x3 nearest pixels; the sky is seen by all.

    S=9223372036854775827   # issue 19's held-out seed, 2^63 + 19
    for k in 2 3 4; do
      sed "s/^reference_camera: cam1/reference_camera: cam$k/" launch_configs/rig_deep360.yaml > /tmp/ref$k.yaml
      mode360 synth --rig /tmp/ref$k.yaml --scene objects --frames 4 --first-frame 60 --width 512 --seed $S --out /tmp/ref$k.mcap
    done
    mode360 replay /tmp/mode360_issue19/objects_w512_f4.mcap --out /tmp/objects_out.mcap
    python models/visibility_split.py launch_configs/rig_deep360.yaml /tmp/objects_out.mcap cam2=/tmp/ref2.mcap cam3=/tmp/ref3.mcap cam4=/tmp/ref4.mcap

Needs numpy and mcap-ros2-support (the interop venv of tests/interop/setup.sh).
"""
import re
import sys

import numpy as np
from mcap_ros2.reader import read_ros2_messages

SEEN_TOLERANCE = 0.05  # relative range difference
DELTA1 = 1.25
SKY_M = 999.0  # ground truth at or beyond this is the sky (bags keep it at max depth 1000 m)


def depth_images(path, topic):
    return [
        np.frombuffer(bytes(m.ros_msg.data), dtype=np.float32).reshape(m.ros_msg.height, m.ros_msg.width)
        for m in read_ros2_messages(path, topics=[topic])
    ]


def camera_centres(rig_yaml):
    """name -> rig-frame translation, and the reference camera's name (flow-style rig files)."""
    text = open(rig_yaml).read()
    reference = re.search(r"^reference_camera:\s*(\S+)", text, re.M).group(1)
    centres = {}
    for block in re.split(r"^\s*- name:", text, flags=re.M)[1:]:
        name = block.split()[0]
        t = re.search(r"translation:\s*\[([^\]]+)\]", block).group(1)
        q = re.search(r"rotation_xyzw:\s*\[([^\]]+)\]", block).group(1)
        if [float(x) for x in q.split(",")] != [0.0, 0.0, 0.0, 1.0]:
            sys.exit(f"{rig_yaml}: camera {name} is rotated; this script handles unrotated cameras only")
        centres[name] = np.array([float(x) for x in t.split(",")])
    return centres, reference


def erp_directions(h, w):
    v, u = np.mgrid[0:h, 0:w]
    lon = np.pi * (1 - 2 * (u + 0.5) / w)
    lat = np.pi / 2 - np.pi * (v + 0.5) / h
    return np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], -1)


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    centres, reference = camera_centres(sys.argv[1])
    truth = depth_images(sys.argv[2], "/ground_truth/depth")
    estimate = depth_images(sys.argv[2], "/depth")
    others = {}
    for arg in sys.argv[3:]:
        name, path = arg.split("=", 1)
        others[name] = depth_images(path, "/ground_truth/depth")
    h, w = truth[0].shape
    dirs = erp_directions(h, w)
    cameras = 1 + len(others)
    total = np.zeros(cameras + 1)
    right = np.zeros(cameras + 1)
    for f, (g, p) in enumerate(zip(truth, estimate)):
        p = np.where(np.isposinf(p), 1000.0, p)
        ok = np.maximum(p / g, g / p) < DELTA1
        points = centres[reference] + dirs * g[..., None]
        seen_by = np.ones(g.shape, dtype=int)
        for name, images in others.items():
            d = points - centres[name]
            r = np.linalg.norm(d, axis=-1)
            d /= r[..., None]
            lat = np.arcsin(np.clip(d[..., 2], -1, 1))
            lon = np.arctan2(d[..., 1], d[..., 0])
            u = np.round((1 - lon / np.pi) * w / 2 - 0.5).astype(int)
            v = np.round((np.pi / 2 - lat) * h / np.pi - 0.5).astype(int)
            best = np.full(g.shape, np.inf)
            for du in (-1, 0, 1):
                for dv in (-1, 0, 1):
                    other = images[f][np.clip(v + dv, 0, h - 1), (u + du) % w]
                    best = np.minimum(best, np.abs(other - r) / r)
            seen_by += (best < SEEN_TOLERANCE) | (g >= SKY_M)
        for c in range(1, cameras + 1):
            total[c] += (seen_by == c).sum()
            right[c] += ok[seen_by == c].sum()
    n = total.sum()
    print(f"{len(truth)} frames, δ1 {100 * right.sum() / n:.2f} %")
    print("| seen by | share of pixels % | δ1 % | δ1 points lost |")
    print("|---|---|---|---|")
    for c in range(1, cameras + 1):
        d1 = 100 * right[c] / total[c] if total[c] else float("nan")
        print(f"| {c} camera(s) | {100 * total[c] / n:.1f} | {d1:.1f} | {100 * (total[c] - right[c]) / n:.1f} |")


if __name__ == "__main__":
    main()
