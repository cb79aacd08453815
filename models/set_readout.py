#!/usr/bin/env python3
"""Sets the inference choices of an SSMODE weights file in place: `far_parallax_cells`,
`far_plane_probability`, `refine_radius_cells` and `seam_pad_cells` in its `mode360.config`
header metadata. The tensors are left byte for byte as they are (only the header is rewritten);
what changes is how they are applied: the far-plane test (models/README.md, "Readout"), the
edge refinement ("Edge refinement"; 0 turns it off) and the aggregation's longitude wrap
("Longitude seam"; 0 turns it off).

    models/set_readout.py WEIGHTS [--far-parallax-cells 0.25] [--far-plane-probability 0.5]
                                  [--refine-radius-cells 2] [--seam-pad-cells N]
"""
import argparse
import json
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tools"))
from safetensors_file import read, write  # noqa: E402  (tools/safetensors_file.py)

CONFIG_KEY = "mode360.config"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("weights")
    ap.add_argument("--far-parallax-cells", type=float, default=0.25)
    ap.add_argument("--far-plane-probability", type=float, default=0.5)
    ap.add_argument("--refine-radius-cells", type=int, default=2)
    ap.add_argument("--seam-pad-cells", type=int, default=None,
                    help="default: as the file has it (missing: 0, no wrap)")
    args = ap.parse_args()
    header, body = read(args.weights)
    try:
        cfg = json.loads(header["__metadata__"][CONFIG_KEY])
    except (ValueError, KeyError) as e:
        sys.exit(f"{args.weights}: no readable '{CONFIG_KEY}' header metadata ({e})")
    keys = ("far_parallax_cells", "far_plane_probability", "refine_radius_cells", "seam_pad_cells")
    before = {k: cfg.get(k) for k in keys}
    cfg["far_parallax_cells"] = args.far_parallax_cells
    cfg["far_plane_probability"] = args.far_plane_probability
    cfg["refine_radius_cells"] = args.refine_radius_cells
    if args.seam_pad_cells is not None:
        cfg["seam_pad_cells"] = args.seam_pad_cells
    header["__metadata__"][CONFIG_KEY] = json.dumps(cfg, separators=(",", ":"))
    write(args.weights, header, body)
    changes = ", ".join(f"{k} {before[k]} -> {cfg[k]}" for k in keys)
    print(f"{args.weights}: {changes}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
