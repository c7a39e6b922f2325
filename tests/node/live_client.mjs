// Connects to `ehactl run --live` with Foxglove's own protocol client library
// (`FoxgloveClient` from @foxglove/ws-protocol, which offers the subprotocol
// `foxglove.websocket.v1`) over the `ws` WebSocket package, subscribes to one topic and decodes
// its CDR messages with Foxglove's ROS 2 decoder (@foxglove/rosmsg parses the advertised
// ros2msg schema, @foxglove/rosmsg2-serialization reads the CDR payload).
//
// Usage: node live_client.mjs WS_URL [TOPIC] [MAX_MESSAGES] [TIMEOUT_S]
// Prints one JSON object on stdout when the server closes, MAX_MESSAGES were decoded or
// TIMEOUT_S passed; exit 0 unless the client could not connect or a message did not decode.

// The package is CommonJS: its named exports come through the default import under Node.
import wsProtocol from "@foxglove/ws-protocol";
import { parse as parseRosmsg } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg2-serialization";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;

const [url, topic = "/control", maxArg = "0", timeoutArg = "30"] = process.argv.slice(2);
if (!url) {
  console.error("usage: node live_client.mjs WS_URL [TOPIC] [MAX_MESSAGES] [TIMEOUT_S]");
  process.exit(2);
}
const maxMessages = Number(maxArg);
const timeoutMs = Number(timeoutArg) * 1000;

const result = {
  subprotocol: null,
  server_name: null,
  channel: null,
  messages: 0,
  decoded: [],
  log_times_ns: [],
  trailing_bytes: 0,
  errors: [],
  close_code: null,
};

const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
let reader = null;
let subId = null;
let finished = false;

function finish(code) {
  if (finished) return;
  finished = true;
  // BigInt is not JSON: log times as decimal strings.
  result.log_times_ns = result.log_times_ns.map((t) => t.toString());
  try {
    client.close();
  } catch {
    // already closed
  }
  // Exit only once the whole line is out: stdout to a pipe is asynchronous in Node.
  process.stdout.write(JSON.stringify(result) + "\n", () => process.exit(code));
}

client.on("open", () => {
  result.subprotocol = ws.protocol;
});
client.on("error", (err) => {
  result.errors.push(String(err?.message ?? err));
  if (result.subprotocol === null) finish(1);
});
client.on("close", (ev) => {
  result.close_code = ev?.code ?? null;
  finish(result.errors.length ? 1 : 0);
});
client.on("serverInfo", (info) => {
  result.server_name = info.name;
});
client.on("advertise", (channels) => {
  for (const ch of channels) {
    if (ch.topic !== topic || subId !== null) continue;
    result.channel = {
      id: ch.id,
      topic: ch.topic,
      encoding: ch.encoding,
      schemaName: ch.schemaName,
      schemaEncoding: ch.schemaEncoding,
    };
    if (ch.encoding !== "cdr" || ch.schemaEncoding !== "ros2msg") {
      result.errors.push(`${topic}: encoding ${ch.encoding}/${ch.schemaEncoding}, expected cdr/ros2msg`);
      finish(1);
      return;
    }
    reader = new MessageReader(parseRosmsg(ch.schema, { ros2: true }));
    subId = client.subscribe(ch.id);
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  if (subscriptionId !== subId || reader === null) return;
  try {
    const msg = reader.readMessage(data);
    if (reader.lastReadHadTrailingBytes()) result.trailing_bytes += 1;
    result.messages += 1;
    result.decoded.push({ cycle: Number(msg.cycle), t: msg.t });
    result.log_times_ns.push(timestamp);
  } catch (err) {
    result.errors.push(`decode: ${err?.message ?? err}`);
    finish(1);
    return;
  }
  if (maxMessages > 0 && result.messages >= maxMessages) finish(0);
});

setTimeout(() => {
  result.errors.push(`timeout after ${timeoutArg} s`);
  finish(result.messages > 0 ? 0 : 1);
}, timeoutMs);
