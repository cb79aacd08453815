#!/usr/bin/env python3
"""Decode `depth/compressedDepth` of a mode360 output bag independently and compare it with
the 32FC1 `depth` of the same stamps.

Usage: check_compressed_depth.py BAG.mcap

Reads the bag with mcap + mcap_ros2 (the bag's own ros2msg schemas). Decodes each
compressedDepth message from image_transport's format description alone: `format` names
32FC1 and compressedDepth; `data` is a 12-byte little-endian header (int32 compressionFormat,
0 = inverse depth; float32 depthParam[2] = A, B) and a PNG of 16-bit grayscale codes q,
decoded here with zlib and the PNG filter rules (no image library); range = A / (q - B) for
q > 0, NaN for q = 0. The 32FC1 image is read as little-endian float32 rows of `step` bytes.

Prints one JSON line: {"frames", "pixels", "max_rel_err" (over pixels finite in both),
"nan_where_invalid" (q = 0 exactly where depth is not finite or not below the maximum),
"format", "quant_a", "quant_b", "max_depth_m"}; exits 1 on a malformed message.
"""

import json
import math
import struct
import sys
import zlib

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
HEADER_BYTES = 12


def paeth(a, b, c):
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    if pa <= pb and pa <= pc:
        return a
    return b if pb <= pc else c


def decode_png_gray16(png):
    if not png.startswith(PNG_SIGNATURE):
        raise ValueError("no PNG signature after the 12-byte header")
    pos, idat, width, height = len(PNG_SIGNATURE), b"", None, None
    while pos < len(png):
        (length,) = struct.unpack(">I", png[pos : pos + 4])
        kind = png[pos + 4 : pos + 8]
        body = png[pos + 8 : pos + 8 + length]
        pos += 12 + length
        if kind == b"IHDR":
            width, height, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", body)
            if (depth, colour, interlace) != (16, 0, 0):
                raise ValueError(f"PNG is not 16-bit grayscale non-interlaced: {depth} {colour} {interlace}")
        elif kind == b"IDAT":
            idat += body
        elif kind == b"IEND":
            break
    raw = zlib.decompress(idat)
    bpp, stride = 2, 2 * width
    rows, prev, off = [], bytearray(stride), 0
    for _ in range(height):
        ftype = raw[off]
        line = bytearray(raw[off + 1 : off + 1 + stride])
        off += 1 + stride
        for i in range(stride):
            a = line[i - bpp] if i >= bpp else 0
            b = prev[i]
            c = prev[i - bpp] if i >= bpp else 0
            if ftype == 1:
                line[i] = (line[i] + a) & 0xFF
            elif ftype == 2:
                line[i] = (line[i] + b) & 0xFF
            elif ftype == 3:
                line[i] = (line[i] + (a + b) // 2) & 0xFF
            elif ftype == 4:
                line[i] = (line[i] + paeth(a, b, c)) & 0xFF
            elif ftype != 0:
                raise ValueError(f"unknown PNG filter {ftype}")
        rows.append(list(struct.unpack(f">{width}H", bytes(line))))
        prev = line
    return width, height, rows


def main():
    depth, compressed, info = {}, {}, {}
    with open(sys.argv[1], "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages(topics=["/depth", "/depth/compressedDepth"]):
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            (depth if channel.topic == "/depth" else compressed)[stamp] = msg
        for record in reader.iter_metadata():
            if record.name == "mode360.synth":
                info = dict(record.metadata)
    max_depth = float(info.get("max_depth_m", "1000"))
    frames = pixels = 0
    max_rel, nan_ok = 0.0, True
    fmt, qa, qb = "", None, None
    for stamp, c in sorted(compressed.items()):
        fmt = c.format
        if not (fmt.startswith("32FC1") and "compressedDepth" in fmt):
            raise SystemExit(f"stamp {stamp}: format '{fmt}'")
        data = bytes(c.data)
        comp, qa, qb = struct.unpack("<iff", data[:HEADER_BYTES])
        if comp != 0:
            raise SystemExit(f"stamp {stamp}: compressionFormat {comp}")
        w, h, codes = decode_png_gray16(data[HEADER_BYTES:])
        d = depth[stamp]
        if (d.width, d.height, d.encoding) != (w, h, "32FC1"):
            raise SystemExit(f"stamp {stamp}: depth {d.width}x{d.height} {d.encoding} vs PNG {w}x{h}")
        raw = bytes(d.data)
        for v in range(h):
            for u in range(w):
                (r,) = struct.unpack_from("<f", raw, v * d.step + 4 * u)
                q = codes[v][u]
                measurable = math.isfinite(r) and 0.0 < r < max_depth
                if (q == 0) == measurable:
                    nan_ok = False
                if q and measurable:
                    got = qa / (q - qb)
                    max_rel = max(max_rel, abs(got - r) / r)
                pixels += 1
        frames += 1
    print(json.dumps({"frames": frames, "pixels": pixels, "max_rel_err": max_rel,
                      "nan_where_invalid": nan_ok, "format": fmt, "quant_a": qa,
                      "quant_b": qb, "max_depth_m": max_depth}))


if __name__ == "__main__":
    main()
