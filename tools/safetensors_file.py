"""Reading and writing safetensors files without third-party packages, for
tools/average_weights.py: the 8-byte little-endian header length, the
JSON header (padded with spaces to a multiple of 8 bytes), then the tensor bytes."""
import json
import os
import struct
import sys

HEADER_ALIGN = 8


def read(path):
    """(header dict, the tensor bytes after the header) of a safetensors file; exits naming the
    file when it is not one."""
    with open(path, "rb") as f:
        data = f.read()
    if len(data) < 8:
        sys.exit(f"{path}: not a safetensors file (shorter than its length prefix)")
    (n,) = struct.unpack("<Q", data[:8])
    try:
        header = json.loads(data[8 : 8 + n])
    except ValueError as e:
        sys.exit(f"{path}: unreadable safetensors header ({e})")
    return header, data[8 + n :]


def write(path, header, body):
    """Writes `header` and `body` to `path` through a temporary file renamed into place."""
    raw = json.dumps(header, separators=(",", ":")).encode()
    raw += b" " * ((HEADER_ALIGN - len(raw) % HEADER_ALIGN) % HEADER_ALIGN)
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(struct.pack("<Q", len(raw)) + raw + body)
    os.replace(tmp, path)
