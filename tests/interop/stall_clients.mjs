// N Foxglove clients that subscribe to every channel and then never read (their TCP sockets
// paused): the load of `tests/interop/live_view_memory.sh`.
// Usage: MODE360_NODE_DIR=DIR node stall_clients.mjs ws://HOST:PORT N HOLD_S
import { createRequire } from "node:module";
import path from "node:path";
const nodeDir = process.env.MODE360_NODE_DIR;
const require = createRequire(path.join(path.resolve(nodeDir), "package.json"));
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");
const [url, countText, holdText] = process.argv.slice(2);
const count = Number(countText), holdMs = 1000 * Number(holdText);
for (let i = 0; i < count; i++) {
  const ws = new WebSocket(url, ["foxglove.sdk.v1", FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
  const client = new FoxgloveClient({ ws });
  let subscribed = 0;
  client.on("advertise", (channels) => {
    for (const c of channels) { client.subscribe(c.id); subscribed++; }
    setTimeout(() => { ws._socket.pause(); console.log(`client ${i}: ${subscribed} channels, paused`); }, 500);
  });
  client.on("error", (e) => console.error(`client ${i}: ${e}`));
}
setTimeout(() => process.exit(0), holdMs);
