#!/usr/bin/env python3
"""Averages SSMODE weights files tensor by tensor (a "model soup"): runs forked from one
checkpoint and trained side by side give one set of weights. The files must hold the same
tensors (names, shapes, F32) and the same `mode360.config` header metadata, which the output
keeps; anything else is an error naming the file and tensor. Needs no third-party package.

    tools/average_weights.py A.safetensors B.safetensors [...] --out SOUP.safetensors

With --extra-from-first, A may hold tensors the others lack (a new stage, such as the fine
head, trained from a file without it): those are copied from A unchanged, the others averaged,
and A's metadata is kept whatever the others' say.
"""
import argparse
import sys
from array import array

from safetensors_file import read, write

METADATA = "__metadata__"


def tensor(path, header, body, name):
    info = header[name]
    if info.get("dtype") != "F32":
        sys.exit(f"{path}: tensor {name} is {info.get('dtype')}, only F32 is averaged")
    start, end = info["data_offsets"]
    values = array("f")
    values.frombytes(body[start:end])
    if sys.byteorder != "little":
        values.byteswap()
    return values


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("weights", nargs="+")
    ap.add_argument("--out", required=True)
    ap.add_argument(
        "--extra-from-first",
        action="store_true",
        help="copy tensors only the first file holds; keep the first file's metadata",
    )
    args = ap.parse_args()
    if len(args.weights) < 2:
        sys.exit("average_weights: give at least two weights files")
    files = [(p, *read(p)) for p in args.weights]
    first_path, first_header, _ = files[0]
    names = sorted(k for k in first_header if k != METADATA)
    for path, header, _ in files[1:]:
        if header.get(METADATA) != first_header.get(METADATA) and not args.extra_from_first:
            sys.exit(f"{path}: header metadata (the network's config) differs from {first_path}")
        other = sorted(k for k in header if k != METADATA)
        missing = sorted(set(names) ^ set(other))
        if args.extra_from_first:
            missing = sorted(set(other) - set(names))
        if missing:
            sys.exit(f"{path}: tensors differ from {first_path}: {', '.join(missing[:5])}")
        for name in other:
            if header[name]["shape"] != first_header[name]["shape"]:
                sys.exit(
                    f"{path}: tensor {name} has shape {header[name]['shape']}, "
                    f"{first_path} {first_header[name]['shape']}"
                )
    out_header = {METADATA: first_header[METADATA]} if METADATA in first_header else {}
    chunks = []
    offset = 0
    for name in names:
        holders = [(path, header, body) for path, header, body in files if name in header]
        sums = None
        for path, header, body in holders:
            values = tensor(path, header, body, name)
            sums = values if sums is None else array("f", (a + b for a, b in zip(sums, values)))
        scale = 1.0 / len(holders)
        mean = array("f", (v * scale for v in sums))
        if sys.byteorder != "little":
            mean.byteswap()
        raw = mean.tobytes()
        out_header[name] = {
            "dtype": "F32",
            "shape": first_header[name]["shape"],
            "data_offsets": [offset, offset + len(raw)],
        }
        chunks.append(raw)
        offset += len(raw)
    write(args.out, out_header, b"".join(chunks))
    print(f"{args.out}: mean of {len(files)} files, {len(names)} tensors, {offset // 4} values")
    return 0


if __name__ == "__main__":
    sys.exit(main())
