#!/usr/bin/env python3
"""Sets the readout of an SSMODE weights file in place: `far_parallax_cells` and
`far_plane_probability` in its `mode360.config` header metadata. The tensors are left byte for
byte as they are (only the header is rewritten), so the network computes the same logits and
only the far-plane test of the readout changes (models/README.md, "Readout").

    models/set_readout.py WEIGHTS [--far-parallax-cells 0.25] [--far-plane-probability 0.5]
"""
import argparse
import json
import os
import struct
import sys

CONFIG_KEY = "mode360.config"
HEADER_ALIGN = 8


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("weights")
    ap.add_argument("--far-parallax-cells", type=float, default=0.25)
    ap.add_argument("--far-plane-probability", type=float, default=0.5)
    args = ap.parse_args()
    with open(args.weights, "rb") as f:
        data = f.read()
    if len(data) < 8:
        sys.exit(f"{args.weights}: not a safetensors file (shorter than its length prefix)")
    (n,) = struct.unpack("<Q", data[:8])
    try:
        header = json.loads(data[8 : 8 + n])
        cfg = json.loads(header["__metadata__"][CONFIG_KEY])
    except (ValueError, KeyError) as e:
        sys.exit(f"{args.weights}: no readable '{CONFIG_KEY}' header metadata ({e})")
    before = (cfg.get("far_parallax_cells"), cfg.get("far_plane_probability"))
    cfg["far_parallax_cells"] = args.far_parallax_cells
    cfg["far_plane_probability"] = args.far_plane_probability
    header["__metadata__"][CONFIG_KEY] = json.dumps(cfg, separators=(",", ":"))
    raw = json.dumps(header, separators=(",", ":")).encode()
    raw += b" " * ((HEADER_ALIGN - len(raw) % HEADER_ALIGN) % HEADER_ALIGN)
    tmp = args.weights + ".tmp"
    with open(tmp, "wb") as f:
        f.write(struct.pack("<Q", len(raw)) + raw + data[8 + n :])
    os.replace(tmp, args.weights)
    print(
        f"{args.weights}: far_parallax_cells {before[0]} -> {args.far_parallax_cells}, "
        f"far_plane_probability {before[1]} -> {args.far_plane_probability}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
