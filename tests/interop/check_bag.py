#!/usr/bin/env python3
"""Decode a mode360 bag with third-party readers and compare it to expected values.

Usage: check_bag.py EXPECTED.json

Readers:
  1. mcap + mcap_ros2 (mcap-ros2-support's DecoderFactory), decoding with the bag's own
     ros2msg schema text;
  2. rosbags: rosbags.rosbag2's MCAP storage reader, decoding with (a) a typestore built
     from the bag's schema text and (b) rosbags' bundled ROS 2 Humble definitions, so the
     field layout is checked against the real ROS definitions too.

EXPECTED.json (written by tests/bags/bag_interop.rs):
  {"bag": path, "profile": "ros2", "metadata": {name: {key: value}},
   "messages": [{"topic", "schema", "log_time_ns" (string), "checks": [[path, value], ...]}]}
Check paths: fields and indices ("a.b[2].c"), "#len" suffix for a length, "@f32le[i]" /
"@u32le[i]" for a little-endian float32 / uint32 element of a byte array; the value "NaN"
matches a NaN. Exits 0 and prints "OK" when everything matches, else prints each mismatch
and exits 1.
"""

import json
import math
import re
import struct
import sys
from collections import defaultdict
from pathlib import Path

SEPARATOR = "=" * 80
SEGMENT = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)")
SUFFIX = re.compile(r"^(.*)@(f32le|u32le)\[(\d+)\]$")
FLOAT_REL_TOL = 1e-12


def field(obj, name):
    if isinstance(obj, dict):
        return obj[name]
    return getattr(obj, name)


def resolve(msg, path):
    """Value at `path` (see module docs)."""
    view = None
    if path.endswith("#len"):
        path, view = path[: -len("#len")], ("len",)
    elif (m := SUFFIX.match(path)) is not None:
        path, view = m.group(1), (m.group(2), int(m.group(3)))
    obj = msg
    for part in path.split("."):
        m = SEGMENT.fullmatch(part)
        if m is None:
            raise ValueError(f"bad path segment {part!r}")
        obj = field(obj, m.group(1))
        for index in re.findall(r"\[(\d+)\]", m.group(2)):
            obj = obj[int(index)]
    if view is None:
        return obj
    if view[0] == "len":
        return len(obj)
    raw = bytes(obj)
    fmt = "<f" if view[0] == "f32le" else "<I"
    return struct.unpack_from(fmt, raw, 4 * view[1])[0]


def matches(actual, expected):
    if expected == "NaN":
        try:
            return math.isnan(float(actual))
        except (TypeError, ValueError):
            return False
    if isinstance(expected, bool):
        return bool(actual) == expected and int(actual) in (0, 1)
    if isinstance(expected, int):
        try:
            return int(actual) == expected and float(actual) == float(expected)
        except (TypeError, ValueError):
            return False
    if isinstance(expected, float):
        try:
            return math.isclose(float(actual), expected, rel_tol=FLOAT_REL_TOL, abs_tol=0.0)
        except (TypeError, ValueError):
            return False
    if isinstance(actual, bytes):
        actual = actual.decode()
    return actual == expected


class Checker:
    def __init__(self, expected):
        self.expected = expected
        self.failures = []
        self.by_topic = defaultdict(list)
        for item in expected["messages"]:
            self.by_topic[item["topic"]].append(item)

    def fail(self, reader, text):
        self.failures.append(f"[{reader}] {text}")

    def check_messages(self, reader, decoded):
        """decoded: list of (topic, schema_name, log_time_ns, message) in log-time order."""
        seen = defaultdict(list)
        for topic, schema, log_time, msg in decoded:
            seen[topic].append((schema, log_time, msg))
        if set(seen) != set(self.by_topic):
            self.fail(reader, f"topics {sorted(seen)} != expected {sorted(self.by_topic)}")
        times = [d[2] for d in decoded]
        if times != sorted(times):
            self.fail(reader, "messages not in log-time order")
        checked = 0
        for topic, wanted in self.by_topic.items():
            got = seen.get(topic, [])
            if len(got) != len(wanted):
                self.fail(reader, f"{topic}: {len(got)} messages, expected {len(wanted)}")
                continue
            for index, (item, (schema, log_time, msg)) in enumerate(zip(wanted, got)):
                where = f"{topic}#{index}"
                if schema != item["schema"]:
                    self.fail(reader, f"{where}: schema {schema!r} != {item['schema']!r}")
                if log_time != int(item["log_time_ns"]):
                    self.fail(reader, f"{where}: log time {log_time} != {item['log_time_ns']}")
                for path, value in item["checks"]:
                    try:
                        actual = resolve(msg, path)
                    except Exception as err:  # noqa: BLE001 - report any access failure
                        self.fail(reader, f"{where}: {path}: cannot read: {err!r}")
                        continue
                    if not matches(actual, value):
                        self.fail(reader, f"{where}: {path} = {actual!r}, expected {value!r}")
                    checked += 1
        print(f"[{reader}] {len(decoded)} messages, {checked} field checks")


def check_with_mcap_ros2(checker, bag):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    decoded = []
    with open(bag, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        if header.profile != checker.expected["profile"]:
            checker.fail("mcap_ros2", f"profile {header.profile!r}")
        for schema, channel, message, msg in reader.iter_decoded_messages(log_time_order=True):
            if schema.encoding != "ros2msg" or channel.message_encoding != "cdr":
                checker.fail(
                    "mcap_ros2",
                    f"{channel.topic}: encodings {schema.encoding!r}/{channel.message_encoding!r}",
                )
            decoded.append((channel.topic, schema.name, message.log_time, msg))
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        for name, entries in checker.expected["metadata"].items():
            if metadata.get(name) != entries:
                checker.fail("mcap", f"metadata {name!r} = {metadata.get(name)!r}, expected {entries!r}")
    checker.check_messages("mcap_ros2", decoded)


def schema_types(schema_name, text):
    """rosbags types of a rosbag2-style ros2msg schema text."""
    from rosbags.typesys import get_types_from_msg

    types = {}
    blocks = re.split(r"^" + SEPARATOR + r"\n", text, flags=re.MULTILINE)
    types.update(get_types_from_msg(blocks[0], schema_name))
    for block in blocks[1:]:
        first, _, body = block.partition("\n")
        if not first.startswith("MSG: "):
            raise ValueError(f"{schema_name}: dependency block starts {first!r}")
        pkg, _, name = first[len("MSG: "):].strip().partition("/")
        types.update(get_types_from_msg(body, f"{pkg}/msg/{name}"))
    return types


def check_with_rosbags(checker, bag):
    from rosbags.rosbag2.storage_mcap import McapReader
    from rosbags.typesys import Stores, get_typestore

    own = get_typestore(Stores.EMPTY)
    humble = get_typestore(Stores.ROS2_HUMBLE)
    reader = McapReader(Path(bag))
    reader.open()
    try:
        registered = set()
        for conn in reader.connections:
            if conn.msgtype in registered:
                continue
            text = conn.msgdef.data
            if isinstance(text, bytes):
                text = text.decode()
            own.register(schema_types(conn.msgtype, text))
            registered.add(conn.msgtype)
        decoded_own, decoded_humble = [], []
        for conn, timestamp, raw in reader.messages(reader.connections):
            decoded_own.append((conn.topic, conn.msgtype, timestamp, own.deserialize_cdr(raw, conn.msgtype)))
            decoded_humble.append(
                (conn.topic, conn.msgtype, timestamp, humble.deserialize_cdr(raw, conn.msgtype))
            )
    finally:
        reader.close()
    checker.check_messages("rosbags (bag schema)", decoded_own)
    checker.check_messages("rosbags (ROS 2 Humble types)", decoded_humble)


def main():
    if len(sys.argv) != 2:
        print(__doc__)
        return 2
    expected = json.loads(Path(sys.argv[1]).read_text())
    checker = Checker(expected)
    for name, run in [("mcap_ros2", check_with_mcap_ros2), ("rosbags", check_with_rosbags)]:
        try:
            run(checker, expected["bag"])
        except Exception as err:  # noqa: BLE001 - a reader crash is a failed check
            checker.fail(name, f"reader raised {err!r}")
    if checker.failures:
        print("\n".join(checker.failures))
        print(f"FAILED: {len(checker.failures)} mismatches")
        return 1
    print("OK: mcap_ros2 and rosbags decode every message as expected")
    return 0


if __name__ == "__main__":
    sys.exit(main())
