#!/usr/bin/env python3
"""Does windowed matching find near surfaces? Spheres against horizontal planes, on true range.

For up to 1,500 random pixels of one frame whose true range is under NEAR_M, the mean ZNCC of
the reference camera's 5x5 window against each other camera's samples of the same window
(mean over the pairs with the reference), with the window's points at:
  - the exact surface: each window pixel at its own true range;
  - the sphere of the centre's true range (what a sphere sweep compares at the truth);
  - the best of 128 spheres uniform in inverse depth from 0.5 to 1000 m;
and winner-take-all δ1 over those spheres and over 64 horizontal planes 0.2 to 4 m under the
reference camera (range h / -r_z per pixel), on the pixels below the horizon. For a rig of
unrotated equirectangular cameras whose output frame is the reference camera (such as
launch_configs/rig_deep360.yaml).

    python models/plane_check.py launch_configs/rig_deep360.yaml /tmp/mode360_issue19/objects_w512_f4.mcap 1

Needs numpy and mcap-ros2-support (the interop venv of tests/interop/setup.sh).
"""
import sys

import numpy as np
from mcap_ros2.reader import read_ros2_messages

from range_texture_split import LUMA
from visibility_split import DELTA1, camera_centres, erp_directions

NEAR_M = 2.0
SAMPLES = 1500
WINDOW_RADIUS = 2  # 5x5, as the photometric sweep
VARIANCE_FLOOR = 1e-6
SPHERES = 128
PLANE_HEIGHTS_M = np.exp(np.linspace(np.log(0.2), np.log(4.0), 64))
MIN_DOWN = 0.01  # -r_z below which a plane is not hit


def frame_message(path, topic, index):
    for i, m in enumerate(read_ros2_messages(path, topics=[topic])):
        if i == index:
            return m.ros_msg
    sys.exit(f"{path}: no frame {index} on {topic}")


def grey(msg):
    rgb = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(msg.height, msg.width, 3)
    return (rgb.astype(np.float64) / 255) @ LUMA


def sample(img, points, offset):
    """Bilinear sample of an ERP image of a camera at `offset` from the reference, at `points`."""
    h, w = img.shape
    d = points - offset
    n = np.linalg.norm(d, axis=-1)
    lat = np.arcsin(np.clip(d[..., 2] / n, -1, 1))
    lon = np.arctan2(d[..., 1], d[..., 0])
    u = (1 - lon / np.pi) * w / 2 - 0.5
    v = np.clip((np.pi / 2 - lat) / np.pi * h - 0.5, 0, h - 1.001)
    u0, v0 = np.floor(u), np.floor(v)
    fu, fv = u - u0, v - v0
    u0 = u0.astype(int) % w
    u1 = (u0 + 1) % w
    v0 = v0.astype(int)
    v1 = np.minimum(v0 + 1, h - 1)
    return (img[v0, u0] * (1 - fu) * (1 - fv) + img[v0, u1] * fu * (1 - fv)
            + img[v1, u0] * (1 - fu) * fv + img[v1, u1] * fu * fv)


def zncc(a, b):
    a = a - a.mean(-1, keepdims=True)
    b = b - b.mean(-1, keepdims=True)
    return (a * b).sum(-1) / np.sqrt((a * a).sum(-1) * (b * b).sum(-1) + VARIANCE_FLOOR * a.shape[-1])


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    rig_yaml, bag, frame = sys.argv[1], sys.argv[2], int(sys.argv[3])
    centres, reference = camera_centres(rig_yaml)
    others = [name for name in centres if name != reference]
    ref_img = grey(frame_message(bag, f"/{reference}/image_raw", frame))
    imgs = [grey(frame_message(bag, f"/{name}/image_raw", frame)) for name in others]
    offsets = [centres[name] - centres[reference] for name in others]
    g = frame_message(bag, "/ground_truth/depth", frame)
    truth = np.frombuffer(bytes(g.data), dtype=np.float32).reshape(g.height, g.width).astype(np.float64)
    h, w = truth.shape
    r = WINDOW_RADIUS
    vv, uu = np.nonzero(truth < NEAR_M)
    inside = (vv >= r) & (vv < h - r)
    vv, uu = vv[inside], uu[inside]
    if len(vv) == 0:
        sys.exit(f"{bag}: frame {frame} has no pixel nearer than {NEAR_M} m")
    pick = np.random.default_rng(0).choice(len(vv), min(SAMPLES, len(vv)), replace=False)
    vv, uu = vv[pick], uu[pick]
    dv, du = np.mgrid[-r:r + 1, -r:r + 1]
    wv = vv[:, None] + dv.ravel()[None]
    wu = (uu[:, None] + du.ravel()[None]) % w
    rays = erp_directions(h, w)[wv, wu]  # (N, 25, 3)
    ref = ref_img[wv, wu]

    def score(range_m):
        points = range_m[..., None] * rays
        return np.mean([zncc(ref, sample(img, points, o)) for img, o in zip(imgs, offsets)], 0)

    centre = truth[vv, uu]
    flat = lambda d: np.broadcast_to(np.asarray(d, dtype=np.float64)[..., None], ref.shape)
    exact = score(truth[wv, wu]).mean()
    at_truth = score(flat(centre)).mean()
    spheres_m = 1 / np.linspace(1 / 0.5, 1 / 1000, SPHERES)
    sphere_scores = np.stack([score(flat(np.full(len(vv), d))) for d in spheres_m])
    down = -rays[..., 2]
    plane_scores = np.stack([
        score(np.where(down > MIN_DOWN, hgt / np.maximum(down, MIN_DOWN), spheres_m[-1]))
        for hgt in PLANE_HEIGHTS_M
    ])
    below = down[:, r * (2 * r + 1) + r] > 5 * MIN_DOWN
    right = lambda est: np.maximum(est / centre, centre / est) < DELTA1
    sphere_wta = spheres_m[sphere_scores.argmax(0)]
    plane_wta = PLANE_HEIGHTS_M[plane_scores.argmax(0)] / np.maximum(down[:, r * (2 * r + 1) + r], MIN_DOWN)
    print(f"{bag} frame {frame}: {len(vv)} pixels nearer than {NEAR_M} m ({below.sum()} below the horizon)")
    print(f"  ZNCC exact surface {exact:.3f} / sphere at the truth {at_truth:.3f} / best sphere {sphere_scores.max(0).mean():.3f}")
    print(f"  WTA δ1 below the horizon: spheres {100 * right(sphere_wta)[below].mean():.1f} % / planes {100 * right(plane_wta)[below].mean():.1f} %")


if __name__ == "__main__":
    main()
