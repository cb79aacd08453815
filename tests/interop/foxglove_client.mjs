// Watch a mode360 node's Foxglove live view with Foxglove's own client and decoders.
//
// Usage: node foxglove_client.mjs URL MAX_DEPTH_M CAMERA_TOPIC [TIMEOUT_S]
//
// Connects to URL (ws://host:port) with @foxglove/ws-protocol's FoxgloveClient over the `ws`
// package, waits for the server to advertise `/depth`, `/points`, `/tf_static` and
// CAMERA_TOPIC, checks that each is `cdr` with a `ros2msg` schema, subscribes to them and
// prints the line `subscribed`. Messages are decoded with @foxglove/rosmsg (the schema text as
// advertised) and @foxglove/rosmsg2-serialization's MessageReader, as the Foxglove app does.
// When it holds a depth image and a point cloud of the same stamp, a camera image and the
// transforms, it prints one JSON line:
//   depth:  stamp_ns, frame_id, encoding, width, height, step, finite_ranges, point_ranges
//           (finite, > 0 and < MAX_DEPTH_M), inf_ranges, nan_ranges, fnv1a64 of the data
//   points: stamp_ns, frame_id, width, height, point_step, fields [name, offset, datatype,
//           count], checked_points, max_xyz_error_m (each point against range x the ERP
//           direction of the n-th pixel with a point range), fnv1a64
//   camera: topic, stamp_ns, encoding, width, height, fnv1a64
//   tf_static: child frames and translations
// and exits 0. Exits 1 with a message on stderr on a timeout or a malformed message.
// Packages are loaded from $MODE360_NODE_DIR/node_modules (default: this script's folder).

import { createRequire } from "node:module";
import path from "node:path";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const nodeDir = process.env.MODE360_NODE_DIR || here;
const require = createRequire(path.join(path.resolve(nodeDir), "package.json"));
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");
const { parse } = require("@foxglove/rosmsg");
const { MessageReader } = require("@foxglove/rosmsg2-serialization");

const [url, maxDepthText, cameraTopic, timeoutText] = process.argv.slice(2);
if (!url || !maxDepthText || !cameraTopic) {
  console.error("usage: node foxglove_client.mjs URL MAX_DEPTH_M CAMERA_TOPIC [TIMEOUT_S]");
  process.exit(2);
}
const maxDepth = Number(maxDepthText);
const timeoutMs = 1000 * Number(timeoutText || 60);
const wanted = ["/depth", "/points", "/tf_static", cameraTopic];
const FLOAT32 = 7;

function fail(text) {
  console.error(`foxglove_client: ${text}`);
  process.exit(1);
}

function fnv1a64(bytes) {
  let h = 0xcbf29ce484222325n;
  for (const b of bytes) {
    h = BigInt.asUintN(64, (h ^ BigInt(b)) * 0x100000001b3n);
  }
  return h.toString(16).padStart(16, "0");
}

function stampNs(header) {
  return (BigInt(header.stamp.sec) * 1000000000n + BigInt(header.stamp.nanosec)).toString();
}

function bytesOf(data) {
  return data instanceof Uint8Array ? data : Uint8Array.from(data);
}

function depthSummary(msg) {
  const data = bytesOf(msg.data);
  if (msg.encoding !== "32FC1") fail(`depth encoding ${msg.encoding}`);
  if (data.length !== msg.step * msg.height) fail("depth data length");
  const dv = new DataView(data.buffer, data.byteOffset, data.byteLength);
  const ranges = [];
  let finite = 0;
  let inf = 0;
  let nan = 0;
  for (let v = 0; v < msg.height; v++) {
    for (let u = 0; u < msg.width; u++) {
      const r = dv.getFloat32(v * msg.step + 4 * u, !msg.is_bigendian);
      ranges.push(r);
      if (Number.isFinite(r)) finite++;
      else if (Number.isNaN(r)) nan++;
      else inf++;
    }
  }
  return {
    summary: {
      stamp_ns: stampNs(msg.header),
      frame_id: msg.header.frame_id,
      encoding: msg.encoding,
      width: msg.width,
      height: msg.height,
      step: msg.step,
      finite_ranges: finite,
      point_ranges: ranges.filter((r) => Number.isFinite(r) && r > 0 && r < maxDepth).length,
      inf_ranges: inf,
      nan_ranges: nan,
      fnv1a64: fnv1a64(data),
    },
    ranges,
  };
}

function erpDirection(u, v, width, height) {
  const lon = Math.PI * (1 - (2 * (u + 0.5)) / width);
  const lat = Math.PI / 2 - (Math.PI * (v + 0.5)) / height;
  return [Math.cos(lat) * Math.cos(lon), Math.cos(lat) * Math.sin(lon), Math.sin(lat)];
}

function pointsSummary(msg, depth) {
  const data = bytesOf(msg.data);
  const fields = msg.fields.map((f) => [f.name, f.offset, f.datatype, f.count]);
  const offset = (name) => {
    const f = msg.fields.find((x) => x.name === name);
    if (!f || f.datatype !== FLOAT32) fail(`points field ${name} missing or not float32`);
    return f.offset;
  };
  const [ox, oy, oz] = [offset("x"), offset("y"), offset("z")];
  const dv = new DataView(data.buffer, data.byteOffset, data.byteLength);
  const le = !msg.is_bigendian;
  const n = msg.width * msg.height;
  if (data.length < n * msg.point_step) fail("points data shorter than width x point_step");
  let k = 0;
  let maxErr = 0;
  const { width, height } = depth.summary;
  for (let v = 0; v < height; v++) {
    for (let u = 0; u < width; u++) {
      const r = depth.ranges[v * width + u];
      if (!(Number.isFinite(r) && r > 0 && r < maxDepth)) continue;
      if (k >= n) fail("fewer points than point ranges");
      const base = k * msg.point_step;
      const p = [dv.getFloat32(base + ox, le), dv.getFloat32(base + oy, le), dv.getFloat32(base + oz, le)];
      const d = erpDirection(u, v, width, height);
      for (let c = 0; c < 3; c++) maxErr = Math.max(maxErr, Math.abs(p[c] - r * d[c]));
      k++;
    }
  }
  return {
    stamp_ns: stampNs(msg.header),
    frame_id: msg.header.frame_id,
    width: msg.width,
    height: msg.height,
    point_step: msg.point_step,
    fields,
    checked_points: k,
    max_xyz_error_m: maxErr,
    fnv1a64: fnv1a64(data),
  };
}

// The Foxglove SDK's server negotiates the protocol under its current name, `foxglove.sdk.v1`
// (the ws-protocol v1 messages with inline schemas); this client library predates the name.
const SDK_SUBPROTOCOL = "foxglove.sdk.v1";
const ws = new WebSocket(url, [SDK_SUBPROTOCOL, FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const timer = setTimeout(() => fail(`timed out after ${timeoutMs} ms`), timeoutMs);
const channels = new Map(); // topic -> channel
const readers = new Map(); // subscription id -> [topic, MessageReader]
const depths = new Map(); // stamp -> depth summary and ranges
const clouds = new Map(); // stamp -> raw points message
let camera = null;
let tfStatic = null;
let subscribed = false;

client.on("error", (e) => fail(`client error: ${e}`));
client.on("close", () => fail("the server closed the connection"));
client.on("advertise", (list) => {
  for (const ch of list) channels.set(ch.topic, ch);
  if (subscribed || !wanted.every((t) => channels.has(t))) return;
  for (const topic of wanted) {
    const ch = channels.get(topic);
    if (ch.encoding !== "cdr" || ch.schemaEncoding !== "ros2msg") {
      fail(`${topic}: encoding ${ch.encoding}, schema encoding ${ch.schemaEncoding}`);
    }
    const reader = new MessageReader(parse(ch.schema, { ros2: true }));
    readers.set(client.subscribe(ch.id), [topic, reader, ch.schemaName]);
  }
  subscribed = true;
  console.log("subscribed");
});
client.on("message", ({ subscriptionId, data }) => {
  const entry = readers.get(subscriptionId);
  if (!entry) return;
  const [topic, reader, schemaName] = entry;
  const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  let msg;
  try {
    msg = reader.readMessage(bytes);
  } catch (e) {
    fail(`${topic} (${schemaName}): cannot decode: ${e}`);
  }
  if (topic === "/depth") {
    const d = depthSummary(msg);
    depths.set(d.summary.stamp_ns, d);
  } else if (topic === "/points") {
    clouds.set(stampNs(msg.header), msg);
  } else if (topic === "/tf_static") {
    tfStatic = msg.transforms.map((t) => ({
      parent: t.header.frame_id,
      child: t.child_frame_id,
      translation: [t.transform.translation.x, t.transform.translation.y, t.transform.translation.z],
    }));
  } else if (topic === cameraTopic) {
    camera = {
      topic,
      schema_name: schemaName,
      stamp_ns: stampNs(msg.header),
      encoding: msg.encoding,
      width: msg.width,
      height: msg.height,
      fnv1a64: fnv1a64(bytesOf(msg.data)),
    };
  }
  const stamp = [...clouds.keys()].find((s) => depths.has(s));
  if (stamp !== undefined && camera && tfStatic) {
    const depth = depths.get(stamp);
    const result = {
      depth: depth.summary,
      points: pointsSummary(clouds.get(stamp), depth),
      camera,
      tf_static: tfStatic,
    };
    console.log(JSON.stringify(result));
    clearTimeout(timer);
    process.exit(0);
  }
});
