// The official Foxglove WebSocket client (@foxglove/ws-protocol, on the `ws` WebSocket, offering
// the subprotocol the library names: foxglove.websocket.v1) against the live view, driven by
// tests/graph/test_official_client.py. Usage: node official_client.cjs URL TOPICS_JSON OUT
//
// It compiles every advertised channel's JSON Schema with Ajv (draft 2020-12, strict mode),
// subscribes to TOPICS once all of them are advertised (each subscription in its own op, as the
// library sends them), validates each message against its schema and writes one JSON line per
// event to OUT: {"event": "open" | "schema" | "subscribed" | "message" | "status" | "close" |
// "error", ...}. A message line has its topic, its log time (decimal string: a u64) and the JSON
// payload as the server sent it. It ends when the server closes the connection.
"use strict";
const fs = require("fs");
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const WebSocket = require("ws");
const Ajv2020 = require("ajv/dist/2020").default;

const [url, topicsJson, outPath] = process.argv.slice(2);
const wanted = new Set(JSON.parse(topicsJson));
const out = fs.openSync(outPath, "w");
const write = (obj) => fs.writeSync(out, JSON.stringify(obj) + "\n");
const ajv = new Ajv2020({ strict: true });
const channels = new Map();          // channel id -> {topic, validate}
const subscriptions = new Map();     // subscription id -> topic
const decoder = new TextDecoder();
let subscribed = false;

const client = new FoxgloveClient({
  ws: new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]),
});
client.on("open", () => write({ event: "open", subprotocol: FoxgloveClient.SUPPORTED_SUBPROTOCOL }));
client.on("error", (err) => write({ event: "error", error: String(err && err.message ? err.message : err) }));
client.on("status", (s) => write({ event: "status", level: s.level, message: s.message }));
client.on("advertise", (list) => {
  for (const ch of list) {
    let validate = null;
    let error = null;
    try {
      validate = ajv.compile(JSON.parse(ch.schema));
    } catch (err) {
      error = String(err.message);
    }
    channels.set(ch.id, { topic: ch.topic, validate });
    write({ event: "schema", topic: ch.topic, schemaName: ch.schemaName, encoding: ch.encoding, error });
  }
  const byTopic = new Map([...channels].map(([id, ch]) => [ch.topic, id]));
  if (!subscribed && [...wanted].every((t) => byTopic.has(t))) {
    subscribed = true;
    for (const topic of wanted) {
      subscriptions.set(client.subscribe(byTopic.get(topic)), topic);
    }
    write({ event: "subscribed", topics: [...wanted] });
  }
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const topic = subscriptions.get(subscriptionId);
  const text = decoder.decode(data);
  const payload = JSON.parse(text);
  const channel = [...channels.values()].find((ch) => ch.topic === topic);
  const valid = channel && channel.validate ? channel.validate(payload) : null;
  write({ event: "message", topic, logTime: timestamp.toString(), payload,
          errors: valid === false ? channel.validate.errors : null });
});
client.on("close", (event) => {
  write({ event: "close", code: event.code });
  fs.closeSync(out);
  process.exit(0);
});
