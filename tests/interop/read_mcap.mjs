// Reads MCAP files with the official TypeScript readers and prints, per file, one JSON line:
// what McapIndexedReader (@mcap/core, opened through @mcap/nodejs's FileHandleReadable, the
// decompressors of @mcap/support) and McapStreamReader (CRC checks on) found. Either reader's
// failure is reported as its error text, never hidden.
//
//   node read_mcap.mjs FILE...
import { open, readFile } from "node:fs/promises";

import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { FileHandleReadable } from "@mcap/nodejs";
import { loadDecompressHandlers } from "@mcap/support";

const decoder = new TextDecoder();

function tally(counts, topic, data, failures) {
  counts[topic] = (counts[topic] ?? 0) + 1;
  try {
    const msg = JSON.parse(decoder.decode(data));
    if (!("t_s" in msg) || !("cycle" in msg)) failures.missingHead[topic] = (failures.missingHead[topic] ?? 0) + 1;
  } catch {
    failures.json += 1;
  }
}

async function indexed(path, decompressHandlers) {
  const handle = await open(path, "r");
  try {
    const reader = await McapIndexedReader.Initialize({
      readable: new FileHandleReadable(handle),
      decompressHandlers,
    });
    const topics = new Map([...reader.channelsById].map(([id, ch]) => [id, ch.topic]));
    const counts = {};
    const failures = { json: 0, missingHead: {} };
    let lastLogTime = -1n;
    let outOfOrder = 0;
    for await (const m of reader.readMessages()) {
      tally(counts, topics.get(m.channelId), m.data, failures);
      if (m.logTime < lastLogTime) outOfOrder += 1;
      lastLogTime = m.logTime;
    }
    const metadata = {};
    for await (const md of reader.readMetadata()) metadata[md.name] = Object.fromEntries(md.metadata);
    const attachments = [];
    for await (const a of reader.readAttachments()) attachments.push(a.name);
    const stats = reader.statistics;
    return {
      counts,
      failures,
      outOfOrder,
      schemas: [...reader.schemasById.values()].map((s) => [s.name, s.encoding]),
      channels: Object.fromEntries(
        [...reader.channelsById.values()].map((c) => [c.topic, reader.schemasById.get(c.schemaId)?.name]),
      ),
      statisticsCount: stats ? Number(stats.messageCount) : null,
      chunks: reader.chunkIndexes.length,
      metadata,
      attachments,
    };
  } catch (err) {
    return { error: String(err?.message ?? err) };
  } finally {
    await handle.close();
  }
}

async function streamed(path, decompressHandlers) {
  const reader = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  reader.append(new Uint8Array(await readFile(path)));
  const topics = new Map();
  const counts = {};
  const failures = { json: 0, missingHead: {} };
  let footer = false;
  try {
    for (let rec; (rec = reader.nextRecord()); ) {
      if (rec.type === "Channel") topics.set(rec.id, rec.topic);
      else if (rec.type === "Message") tally(counts, topics.get(rec.channelId), rec.data, failures);
      else if (rec.type === "Footer") footer = true;
    }
  } catch (err) {
    return { counts, failures, footer, error: String(err?.message ?? err) };
  }
  // A file cut mid-record leaves bytes the reader holds, waiting for the rest.
  return { counts, failures, footer, done: reader.done(), leftoverBytes: reader.bytesRemaining() };
}

const decompressHandlers = await loadDecompressHandlers();
for (const path of process.argv.slice(2)) {
  const out = {
    path,
    indexed: await indexed(path, decompressHandlers),
    stream: await streamed(path, decompressHandlers),
  };
  process.stdout.write(JSON.stringify(out) + "\n");
}
