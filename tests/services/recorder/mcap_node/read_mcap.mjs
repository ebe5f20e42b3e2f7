// Reads a tiplog recording with the TypeScript MCAP implementation (@mcap/core), decodes
// every protobuf message with protobufjs from the schema embedded in the file, and prints a
// JSON summary: per-topic counts, schema names, first/last sequence, and one decoded field
// per message type. The Python test compares it with what the Python reader sees.
import { open } from "node:fs/promises";
import { McapIndexedReader } from "@mcap/core";
import { loadDecompressHandlers, protobufFromBinaryDescriptor } from "@mcap/support";

const path = process.argv[2];
const fh = await open(path, "r");
const readable = {
  size: async () => BigInt((await fh.stat()).size),
  read: async (offset, size) => {
    const buf = Buffer.alloc(Number(size));
    const { bytesRead } = await fh.read(buf, 0, Number(size), Number(offset));
    if (bytesRead !== Number(size)) throw new Error(`short read at ${offset}`);
    return buf;
  },
};
const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers: await loadDecompressHandlers() });
const types = new Map();
const topics = {};
for (const [id, ch] of reader.channelsById) {
  const schema = reader.schemasById.get(ch.schemaId);
  if (ch.messageEncoding !== "protobuf" || schema.encoding !== "protobuf") throw new Error(`${ch.topic}: not protobuf`);
  types.set(id, protobufFromBinaryDescriptor(schema.data).lookupType(schema.name));
  topics[ch.topic] = { schema: schema.name, count: 0, first_sequence: null, last_sequence: null, compression: new Set() };
}
for (const ci of reader.chunkIndexes) for (const t of Object.values(topics)) t.compression.add(ci.compression);
let lastLog = -1n;
let ordered = true;
for await (const msg of reader.readMessages()) {
  const ch = reader.channelsById.get(msg.channelId);
  const t = topics[ch.topic];
  const decoded = types.get(msg.channelId).toObject(types.get(msg.channelId).decode(msg.data), { longs: String, defaults: true });
  if (t.count === 0) t.example = decoded.header ?? { width: decoded.width, height: decoded.height, encoding: decoded.encoding };
  t.count += 1;
  t.first_sequence ??= msg.sequence;
  t.last_sequence = msg.sequence;
  if (msg.logTime < lastLog) ordered = false;
  lastLog = msg.logTime;
}
for (const t of Object.values(topics)) t.compression = [...t.compression].sort();
const stats = reader.statistics;
console.log(JSON.stringify({
  topics,
  message_count: stats ? Number(stats.messageCount) : null,
  chunk_count: reader.chunkIndexes.length,
  metadata: reader.metadataIndexes.map((m) => m.name),
  attachments: reader.attachmentIndexes.map((a) => a.name),
  log_time_ordered: ordered,
}));
await fh.close();
