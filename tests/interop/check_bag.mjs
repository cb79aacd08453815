// Decode a mode360 bag with Foxglove's own libraries and compare it to expected values.
//
// Usage: node check_bag.mjs EXPECTED.json
//
// Reads records with @mcap/core's McapStreamReader (validating CRCs and the end of file),
// parses each schema's ros2msg text with @foxglove/rosmsg and decodes messages with
// @foxglove/rosmsg2-serialization's MessageReader, as the Foxglove app does. EXPECTED.json is
// described in check_bag.py. Packages are loaded from $MODE360_NODE_DIR/node_modules (default:
// this script's folder). Exits 0 and prints "OK" when everything matches.

import { readFileSync } from "node:fs";
import { createRequire } from "node:module";
import path from "node:path";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const nodeDir = process.env.MODE360_NODE_DIR || here;
const require = createRequire(path.join(path.resolve(nodeDir), "package.json"));
const { McapStreamReader } = require("@mcap/core");
const { parse } = require("@foxglove/rosmsg");
const { MessageReader } = require("@foxglove/rosmsg2-serialization");

const SEGMENT = /^([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)$/;
const SUFFIX = /^(.*)@(f32le|u32le)\[(\d+)\]$/;
const FLOAT_REL_TOL = 1e-12;

function resolve(msg, fieldPath) {
  let view = null;
  let p = fieldPath;
  const suffix = SUFFIX.exec(p);
  if (p.endsWith("#len")) {
    p = p.slice(0, -"#len".length);
    view = ["len"];
  } else if (suffix) {
    p = suffix[1];
    view = [suffix[2], Number(suffix[3])];
  }
  let obj = msg;
  for (const part of p.split(".")) {
    const m = SEGMENT.exec(part);
    if (!m) throw new Error(`bad path segment ${part}`);
    obj = obj[m[1]];
    if (obj === undefined) throw new Error(`no field ${m[1]}`);
    for (const index of m[2].matchAll(/\[(\d+)\]/g)) {
      obj = obj[Number(index[1])];
    }
  }
  if (view === null) return obj;
  if (view[0] === "len") return obj.length;
  const bytes = obj instanceof Uint8Array ? obj : Uint8Array.from(obj);
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  return view[0] === "f32le" ? dv.getFloat32(4 * view[1], true) : dv.getUint32(4 * view[1], true);
}

function matches(actual, expected) {
  if (expected === "NaN") return typeof actual === "number" && Number.isNaN(actual);
  if (typeof expected === "boolean") return actual === expected;
  if (typeof expected === "number") {
    const a = typeof actual === "bigint" ? Number(actual) : actual;
    if (typeof a !== "number") return false;
    if (Number.isInteger(expected)) return a === expected;
    return Math.abs(a - expected) <= FLOAT_REL_TOL * Math.abs(expected);
  }
  return actual === expected;
}

function main() {
  if (process.argv.length !== 3) {
    console.log("usage: node check_bag.mjs EXPECTED.json");
    return 2;
  }
  const expected = JSON.parse(readFileSync(process.argv[2], "utf8"));
  const failures = [];
  const fail = (text) => failures.push(`[foxglove] ${text}`);

  const reader = new McapStreamReader({ validateCrcs: true });
  reader.append(new Uint8Array(readFileSync(expected.bag)));
  const schemas = new Map();
  const channels = new Map();
  const decoders = new Map();
  const decoded = [];
  const metadata = new Map();
  let profile = null;
  for (let record; (record = reader.nextRecord()); ) {
    switch (record.type) {
      case "Header":
        profile = record.profile;
        break;
      case "Schema":
        schemas.set(record.id, record);
        break;
      case "Channel":
        channels.set(record.id, record);
        break;
      case "Metadata":
        metadata.set(record.name, Object.fromEntries(record.metadata));
        break;
      case "Message": {
        const channel = channels.get(record.channelId);
        if (!channel) throw new Error(`message on unknown channel ${record.channelId}`);
        const schema = schemas.get(channel.schemaId);
        if (schema.encoding !== "ros2msg" || channel.messageEncoding !== "cdr") {
          fail(`${channel.topic}: encodings ${schema.encoding}/${channel.messageEncoding}`);
        }
        if (!decoders.has(schema.id)) {
          const text = new TextDecoder().decode(schema.data);
          decoders.set(schema.id, new MessageReader(parse(text, { ros2: true })));
        }
        const msg = decoders.get(schema.id).readMessage(record.data);
        decoded.push({ topic: channel.topic, schema: schema.name, logTime: record.logTime, msg });
        break;
      }
      default:
        break;
    }
  }
  if (!reader.done()) fail("stream reader did not reach the end of the file");
  if (profile !== expected.profile) fail(`profile ${profile}`);
  for (const [name, entries] of Object.entries(expected.metadata)) {
    const got = JSON.stringify(metadata.get(name));
    if (got !== JSON.stringify(entries)) fail(`metadata ${name} = ${got}`);
  }

  decoded.sort((a, b) => (a.logTime < b.logTime ? -1 : a.logTime > b.logTime ? 1 : 0));
  const seen = new Map();
  for (const d of decoded) {
    if (!seen.has(d.topic)) seen.set(d.topic, []);
    seen.get(d.topic).push(d);
  }
  const wantedByTopic = new Map();
  for (const item of expected.messages) {
    if (!wantedByTopic.has(item.topic)) wantedByTopic.set(item.topic, []);
    wantedByTopic.get(item.topic).push(item);
  }
  const topicsGot = [...seen.keys()].sort().join(",");
  const topicsWanted = [...wantedByTopic.keys()].sort().join(",");
  if (topicsGot !== topicsWanted) fail(`topics ${topicsGot} != ${topicsWanted}`);
  let checked = 0;
  for (const [topic, wanted] of wantedByTopic) {
    const got = seen.get(topic) ?? [];
    if (got.length !== wanted.length) {
      fail(`${topic}: ${got.length} messages, expected ${wanted.length}`);
      continue;
    }
    wanted.forEach((item, index) => {
      const where = `${topic}#${index}`;
      const d = got[index];
      if (d.schema !== item.schema) fail(`${where}: schema ${d.schema} != ${item.schema}`);
      if (d.logTime !== BigInt(item.log_time_ns)) {
        fail(`${where}: log time ${d.logTime} != ${item.log_time_ns}`);
      }
      for (const [fieldPath, value] of item.checks) {
        let actual;
        try {
          actual = resolve(d.msg, fieldPath);
        } catch (err) {
          fail(`${where}: ${fieldPath}: cannot read: ${err}`);
          continue;
        }
        if (!matches(actual, value)) {
          fail(`${where}: ${fieldPath} = ${String(actual)}, expected ${JSON.stringify(value)}`);
        }
        checked += 1;
      }
    });
  }
  console.log(`[foxglove] ${decoded.length} messages, ${checked} field checks`);
  if (failures.length > 0) {
    console.log(failures.join("\n"));
    console.log(`FAILED: ${failures.length} mismatches`);
    return 1;
  }
  console.log("OK: @mcap/core + @foxglove/rosmsg2-serialization decode every message as expected");
  return 0;
}

process.exitCode = main();
