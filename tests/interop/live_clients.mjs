// Connects clients built from @foxglove/ws-protocol's FoxgloveClient (the protocol client of
// Foxglove's open tools) over the `ws` package's WebSocket to a live view, all at once, and
// prints one JSON line: per client, the subprotocols it offered, the one the server chose, the
// channels advertised, and the messages received per subscribed topic (their t_s and cycle)
// over a window; or the server's refusal (HTTP status and body).
//
//   node live_clients.mjs URL SECONDS SETTLE_SECONDS TOPIC...
//
// Clients: "both" offers foxglove.sdk.v1 and foxglove.websocket.v1 (as Lichtblick does since
// it learned the SDK's name), "sdk" offers foxglove.sdk.v1 only (the Foxglove app), "v1" offers
// FoxgloveClient.SUPPORTED_SUBPROTOCOL only (foxglove.websocket.v1: the client as shipped).
import wsProtocol from "@foxglove/ws-protocol";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;

const [url, seconds, settle, ...topics] = process.argv.slice(2);
const windowMs = Number(seconds) * 1000;
const settleMs = Number(settle) * 1000;
const SDK = "foxglove.sdk.v1";
const OFFERS = {
  both: [FoxgloveClient.SUPPORTED_SUBPROTOCOL, SDK], // Lichtblick's list, in its order
  sdk: [SDK],
  v1: [FoxgloveClient.SUPPORTED_SUBPROTOCOL],
};
const decoder = new TextDecoder();

function run(kind) {
  return new Promise((resolve) => {
    const out = { kind, offered: OFFERS[kind], protocol: null, advertised: {}, received: {} };
    const ws = new WebSocket(url, OFFERS[kind]);
    ws.on("unexpected-response", (_req, res) => {
      let body = "";
      res.on("data", (c) => (body += c));
      res.on("end", () => {
        out.refused = { status: res.statusCode, body };
        ws.terminate();
        resolve(out);
      });
    });
    const client = new FoxgloveClient({ ws });
    const subs = new Map();
    let start = null;
    let timer = null;
    client.on("error", (err) => {
      out.errors = [...(out.errors ?? []), String(err?.message ?? err)];
    });
    client.on("open", () => {
      out.protocol = ws.protocol;
    });
    client.on("serverInfo", (info) => {
      out.serverName = info.name;
    });
    client.on("advertise", (channels) => {
      for (const ch of channels) {
        out.advertised[ch.topic] = { schemaName: ch.schemaName, encoding: ch.encoding };
        if (topics.includes(ch.topic) && ![...subs.values()].includes(ch.topic)) {
          subs.set(client.subscribe(ch.id), ch.topic);
          out.received[ch.topic] = [];
        }
      }
      if (timer === null && subs.size === topics.length) {
        start = Date.now() + settleMs;
        timer = setTimeout(() => {
          client.close();
          resolve(out);
        }, settleMs + windowMs);
      }
    });
    client.on("message", ({ subscriptionId, data }) => {
      if (start === null || Date.now() < start) return;
      const topic = subs.get(subscriptionId);
      const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
      let msg;
      try {
        msg = JSON.parse(decoder.decode(bytes));
      } catch {
        msg = { binary: bytes.byteLength };
      }
      out.received[topic].push([msg.t_s ?? null, msg.cycle ?? null]);
    });
    client.on("close", () => {
      if (timer === null) resolve(out);
    });
  });
}

const results = await Promise.all(Object.keys(OFFERS).map(run));
process.stdout.write(JSON.stringify({ windowSeconds: Number(seconds), clients: results }) + "\n");
process.exit(0);
