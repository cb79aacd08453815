#!/usr/bin/env python3
"""δ1 points lost on a replayed bag, split by ground-truth range and by local texture.

A depth estimate that fails on flat (textureless) surfaces lacks evidence that no matching can
find in those pixels; one that fails on textured surfaces had the evidence and misread it. For
every frame of each replayed bag this script measures the standard deviation of the reference
image's luminance (0..1) in a 7x7 window around each pixel (wrapping in longitude) and
tabulates, per texture class and ground-truth range band, the points of δ1 lost (the share of
all pixels that are wrong) with the share of pixels in brackets; the sky is left out. It also
prints each frame's δ1 and, per range band, how many of the misses are too far.

    mode360 replay /tmp/mode360_issue19/objects_w512_f4.mcap --out /tmp/objects_ssmode.mcap
    mode360 replay /tmp/mode360_issue19/objects_w512_f4.mcap --estimator photometric --out /tmp/objects_sweep.mcap
    python models/range_texture_split.py /tmp/objects_ssmode.mcap /tmp/objects_sweep.mcap

Needs numpy and mcap-ros2-support (the interop venv of tests/interop/setup.sh).
"""
import sys

import numpy as np
from mcap_ros2.reader import read_ros2_messages

from visibility_split import DELTA1, SKY_M

WINDOW_RADIUS = 3  # 7x7 pixels
# local luminance standard deviation classes: flat, faint, textured
TEXTURE_EDGES = [0.0, 0.01, 0.03, np.inf]
TEXTURE_NAMES = ["flat (< 0.01)", "faint (< 0.03)", "textured"]
RANGE_EDGES_M = [0.0, 2.0, 5.0, 20.0, 80.0, SKY_M]
LUMA = np.array([0.299, 0.587, 0.114])


def messages(path, topic):
    return [m.ros_msg for m in read_ros2_messages(path, topics=[topic])]


def depth(msg):
    d = np.frombuffer(bytes(msg.data), dtype=np.float32).reshape(msg.height, msg.width)
    return np.where(np.isfinite(d), d, 1000.0)


def box_mean(a, r):
    """Mean over a (2r+1)^2 window, wrapping in longitude and clamping in latitude."""
    p = np.pad(a, ((r, r), (0, 0)), mode="edge")
    p = np.concatenate([p[:, -r:], p, p[:, :r]], 1)
    c = np.pad(p.cumsum(0).cumsum(1), ((1, 0), (1, 0)))
    k = 2 * r + 1
    h, w = a.shape
    return (c[k:k + h, k:k + w] - c[:h, k:k + w] - c[k:k + h, :w] + c[:h, :w]) / k**2


def local_std(msg):
    if msg.encoding != "rgb8":
        sys.exit(f"reference image encoding {msg.encoding}: this script reads rgb8")
    rgb = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(msg.height, msg.width, 3)
    y = (rgb.astype(np.float64) / 255) @ LUMA
    return np.sqrt(np.maximum(box_mean(y * y, WINDOW_RADIUS) - box_mean(y, WINDOW_RADIUS) ** 2, 0))


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    bands = list(zip(RANGE_EDGES_M[:-1], RANGE_EDGES_M[1:]))
    for path in sys.argv[1:]:
        truths = messages(path, "/ground_truth/depth")
        estimates = messages(path, "/depth")
        images = messages(path, "/cam1/image_raw")
        lost = np.zeros((len(TEXTURE_NAMES), len(bands)))
        share = np.zeros_like(lost)
        too_far = np.zeros(len(bands))
        missed = np.zeros(len(bands))
        pixels = 0
        frame_d1 = []
        for g_msg, p_msg, im in zip(truths, estimates, images):
            g, p = depth(g_msg), depth(p_msg)
            if p.shape != g.shape:
                sys.exit(f"{path}: estimate {p.shape} and ground truth {g.shape} differ in size")
            wrong = np.maximum(p / g, g / p) >= DELTA1
            frame_d1.append(100 * (1 - wrong.mean()))
            sd = local_std(im)
            if sd.shape != g.shape:
                sys.exit(f"{path}: reference image {sd.shape} and depth {g.shape} differ in size")
            pixels += g.size
            for j, (lo, hi) in enumerate(bands):
                in_band = (g >= lo) & (g < hi)
                too_far[j] += (in_band & wrong & (p > g)).sum()
                missed[j] += (in_band & wrong).sum()
                for i in range(len(TEXTURE_NAMES)):
                    m = in_band & (sd >= TEXTURE_EDGES[i]) & (sd < TEXTURE_EDGES[i + 1])
                    share[i, j] += m.sum()
                    lost[i, j] += (m & wrong).sum()
        print(f"{path}: δ1 per frame " + " / ".join(f"{d:.2f}" for d in frame_d1))
        header = " | ".join(f"{lo:g}-{hi:g} m" for lo, hi in bands)
        print(f"| points lost (share of pixels %) | {header} | all ranges |")
        print("|---" * (len(bands) + 2) + "|")
        for i, name in enumerate(TEXTURE_NAMES):
            cells = " | ".join(f"{100 * lost[i, j] / pixels:.2f} ({100 * share[i, j] / pixels:.1f})"
                               for j in range(len(bands)))
            print(f"| {name} | {cells} | {100 * lost[i].sum() / pixels:.2f} ({100 * share[i].sum() / pixels:.1f}) |")
        far = " | ".join(f"{100 * too_far[j] / max(missed[j], 1):.0f}" for j in range(len(bands)))
        print(f"| misses too far, % | {far} | |")


if __name__ == "__main__":
    main()
