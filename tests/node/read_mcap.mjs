#!/usr/bin/env node
// Independent cross-check of an ehactl MCAP log with the official TypeScript library.
//
//   node tests/node/read_mcap.mjs FILE.mcap
//
// Prints one JSON line:
//   {"topics":{"/control":N,...}, "first_t":..., "last_t":..., "contiguous":true, ...}
// and exits 0 only if every check passed (exit 1 on a check failure, after printing the
// JSON with an "errors" list; exit 2 if the file could not be read at all).
//
// What is validated, and by whom:
//  - McapIndexedReader.Initialize validates the footer's summary CRC (when non-zero).
//    readMessages({validateCrcs: true}) (true is also its default) validates the
//    uncompressed CRC of every chunk it loads (when non-zero). The indexed reader does NOT
//    compute the data-section CRC stored in DataEnd: it only exposes it as
//    reader.dataSectionCrc, so this script computes it itself (crc32 of every byte from the
//    start of the file up to the DataEnd record) and compares.
//  - McapStreamReader({validateCrcs: true}) makes a full sequential pass and validates every
//    chunk CRC (and attachment CRCs); it does not check the DataEnd or summary CRCs either.
//  - Zero-valued CRC fields mean "not computed" and make both readers skip the check, so
//    this script reports them and counts a zero chunk/data/summary CRC as an error.
//  - ehactl's LZ4 frames carry no content checksum (the MCAP chunk CRC covers the records;
//    lz4js would ignore one anyway), so a corrupted chunk is caught by the MCAP chunk CRC
//    (or by the size check in the decompress handler below).

import { open, readFile } from "node:fs/promises";
import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { crc32 } from "@foxglove/crc";
import lz4 from "lz4js";

const CDR_TOPICS = ["/control", "/plant"];
const CONTROL_FIELDS = [
  "cycle", "t", "setpoint", "setpoint_rate", "feedback", "error", "command",
  "command_unsat", "p_term", "i_term", "d_term", "ff_term", "force", "position",
  "p_a", "p_b", "spool",
];
const CONTROL_SIZE = 4 + 17 * 8; // CDR header + uint64 + 16 float64, all 8-aligned
const PLANT_SIZE = 4 + 16 * 8 + 1; // CDR header + 16 float64 + bool

const decompressHandlers = {
  lz4: (buffer, decompressedSize) => {
    const n = Number(decompressedSize);
    const out = new Uint8Array(n);
    const written = lz4.decompressFrame(buffer, out);
    if (written !== n) {
      throw new Error(`lz4 chunk decompressed to ${written} bytes, chunk header says ${n}`);
    }
    return out;
  },
};

/** Random-access IReadable over a file handle, for McapIndexedReader. */
function fileReadable(handle, size) {
  return {
    size: async () => BigInt(size),
    read: async (offset, length) => {
      const buf = new Uint8Array(Number(length));
      const { bytesRead } = await handle.read(buf, 0, buf.byteLength, Number(offset));
      if (bytesRead !== buf.byteLength) {
        throw new Error(`short read at ${offset}: ${bytesRead} of ${length} bytes`);
      }
      return buf;
    },
  };
}

function decodeControl(data) {
  if (data.byteLength !== CONTROL_SIZE) {
    throw new Error(`/control payload is ${data.byteLength} bytes, expected ${CONTROL_SIZE}`);
  }
  if (data[0] !== 0x00 || data[1] !== 0x01 || data[2] !== 0x00 || data[3] !== 0x00) {
    throw new Error(`/control CDR header ${Buffer.from(data.subarray(0, 4)).toString("hex")} != 00010000`);
  }
  const view = new DataView(data.buffer, data.byteOffset, data.byteLength);
  const out = { cycle: Number(view.getBigUint64(4, true)) };
  for (let i = 1; i < CONTROL_FIELDS.length; i++) {
    out[CONTROL_FIELDS[i]] = view.getFloat64(4 + 8 * i, true);
  }
  return out;
}

function checkPlantPayload(data, errors) {
  if (data.byteLength !== PLANT_SIZE) {
    errors.push(`/plant payload is ${data.byteLength} bytes, expected ${PLANT_SIZE}`);
  } else if (data[0] !== 0x00 || data[1] !== 0x01 || data[2] !== 0x00 || data[3] !== 0x00) {
    errors.push("/plant CDR header is not 00010000");
  } else if (data[PLANT_SIZE - 1] > 1) {
    errors.push(`/plant bool 'stuck' byte is ${data[PLANT_SIZE - 1]}`);
  }
}

async function indexedPass(path, errors) {
  const handle = await open(path, "r");
  try {
    const { size } = await handle.stat();
    const reader = await McapIndexedReader.Initialize({
      readable: fileReadable(handle, size),
      decompressHandlers,
    });
    const topicOf = new Map([...reader.channelsById].map(([id, ch]) => [id, ch.topic]));
    const topics = {};
    const nextSeq = Object.fromEntries(CDR_TOPICS.map((t) => [t, 0]));
    let contiguous = true;
    let first = null;
    let last = null;
    let plantChecked = 0;
    for await (const msg of reader.readMessages({ validateCrcs: true })) {
      const topic = topicOf.get(msg.channelId);
      topics[topic] = (topics[topic] ?? 0) + 1;
      if (topic in nextSeq) {
        if (msg.sequence !== nextSeq[topic]) {
          if (contiguous) {
            errors.push(`${topic}: sequence ${msg.sequence} where ${nextSeq[topic]} was expected`);
          }
          contiguous = false;
        }
        nextSeq[topic] = msg.sequence + 1;
      }
      if (topic === "/control") {
        if (first === null) {
          first = { data: msg.data.slice(), sequence: msg.sequence, logTime: msg.logTime };
        }
        // copy: the message bytes may borrow from a chunk buffer the reader drops later
        last = { data: msg.data.slice(), sequence: msg.sequence, logTime: msg.logTime };
      } else if (topic === "/plant" && plantChecked < 8) {
        checkPlantPayload(msg.data, errors);
        plantChecked++;
      }
    }
    for (const topic of CDR_TOPICS) {
      if (!topics[topic]) {
        errors.push(`no ${topic} messages`);
        contiguous = false;
      }
    }
    if ((topics["/control"] ?? 0) !== (topics["/plant"] ?? 0)) {
      errors.push(`/control has ${topics["/control"]} messages, /plant ${topics["/plant"]}`);
    }

    // Statistics record must agree with what was read.
    const stats = reader.statistics;
    if (!stats) {
      errors.push("no Statistics record in the summary");
    } else {
      for (const [id, n] of stats.channelMessageCounts) {
        const topic = topicOf.get(id);
        if (Number(n) !== (topics[topic] ?? 0)) {
          errors.push(`Statistics says ${n} messages on ${topic}, read ${topics[topic] ?? 0}`);
        }
      }
    }

    let firstDecoded = null;
    let lastDecoded = null;
    if (first && last) {
      firstDecoded = decodeControl(first.data);
      lastDecoded = decodeControl(last.data);
      for (const [m, d] of [[first, firstDecoded], [last, lastDecoded]]) {
        if (d.cycle !== m.sequence) {
          errors.push(`/control cycle ${d.cycle} != message sequence ${m.sequence}`);
        }
        const tNs = BigInt(Math.round(d.t * 1e9));
        const diff = tNs > m.logTime ? tNs - m.logTime : m.logTime - tNs;
        if (diff > 1n) {
          errors.push(`/control t = ${d.t} s but log_time = ${m.logTime} ns`);
        }
      }
    }
    return {
      reader,
      topics,
      contiguous,
      firstDecoded,
      lastDecoded,
      footer: reader.footer,
      chunkCount: reader.chunkIndexes.length,
    };
  } finally {
    await handle.close();
  }
}

function streamPass(bytes, errors) {
  const reader = new McapStreamReader({ validateCrcs: true, decompressHandlers, includeChunks: true });
  const topicOf = new Map();
  const topics = {};
  const chunkCrcs = [];
  let dataEnd = null;
  reader.append(bytes);
  for (let record; (record = reader.nextRecord()); ) {
    switch (record.type) {
      case "Channel":
        topicOf.set(record.id, record.topic);
        break;
      case "Message": {
        const topic = topicOf.get(record.channelId);
        topics[topic] = (topics[topic] ?? 0) + 1;
        break;
      }
      case "Chunk":
        chunkCrcs.push(record.uncompressedCrc);
        break;
      case "DataEnd":
        dataEnd = record;
        break;
      default:
        break;
    }
  }
  if (!reader.done()) {
    errors.push(`stream reader did not reach the end of a complete MCAP (${reader.bytesRemaining()} bytes left unparsed)`);
  }
  return { topics, chunkCrcs, dataEnd };
}

async function main() {
  const path = process.argv[2];
  if (!path) {
    console.error("usage: node read_mcap.mjs FILE.mcap");
    process.exit(2);
  }
  const errors = [];
  let indexed;
  let stream;
  let bytes;
  try {
    bytes = new Uint8Array(await readFile(path));
    indexed = await indexedPass(path, errors);
    stream = streamPass(bytes, errors);
  } catch (err) {
    console.error(`read_mcap: ${path}: ${err instanceof Error ? err.message : String(err)}`);
    process.exit(2);
  }

  // Stream and indexed passes must see the same messages.
  const allTopics = new Set([...Object.keys(indexed.topics), ...Object.keys(stream.topics)]);
  for (const t of allTopics) {
    if ((indexed.topics[t] ?? 0) !== (stream.topics[t] ?? 0)) {
      errors.push(`${t}: indexed reader read ${indexed.topics[t] ?? 0}, stream reader ${stream.topics[t] ?? 0}`);
    }
  }

  // CRCs: none of them may be zero ("not computed"), and the data-section CRC is checked here
  // because neither reader does it.
  const footer = indexed.footer;
  const crc = {
    summary: footer.summaryCrc,
    data_section: indexed.reader.dataSectionCrc ?? 0,
    chunks: stream.chunkCrcs,
    data_section_ok: null,
  };
  if (footer.summaryCrc === 0) errors.push("footer summary CRC is 0 (not computed)");
  if (stream.chunkCrcs.length !== indexed.chunkCount) {
    errors.push(`stream pass saw ${stream.chunkCrcs.length} chunks, chunk index lists ${indexed.chunkCount}`);
  }
  if (stream.chunkCrcs.some((c) => c === 0)) errors.push("a chunk has uncompressed CRC 0 (not computed)");
  if (!stream.dataEnd) {
    errors.push("no DataEnd record");
  } else if (stream.dataEnd.dataSectionCrc === 0) {
    errors.push("DataEnd data-section CRC is 0 (not computed)");
  } else {
    const dataEndLength = 1n + 8n + 4n;
    const dataEndOffset = footer.summaryStart !== 0n ? footer.summaryStart - dataEndLength : null;
    if (dataEndOffset === null) {
      errors.push("no summary section, cannot locate DataEnd for the data-section CRC");
    } else {
      const actual = crc32(bytes.subarray(0, Number(dataEndOffset)));
      crc.data_section_ok = actual === stream.dataEnd.dataSectionCrc;
      if (!crc.data_section_ok) {
        errors.push(`data-section CRC ${actual} != DataEnd ${stream.dataEnd.dataSectionCrc}`);
      }
    }
  }

  const result = {
    topics: indexed.topics,
    first_t: indexed.firstDecoded?.t ?? null,
    last_t: indexed.lastDecoded?.t ?? null,
    contiguous: indexed.contiguous,
    first_cycle: indexed.firstDecoded?.cycle ?? null,
    last_cycle: indexed.lastDecoded?.cycle ?? null,
    first_control: indexed.firstDecoded,
    last_control: indexed.lastDecoded,
    stream_topics: stream.topics,
    profile: indexed.reader.header.profile,
    library: indexed.reader.header.library,
    crc,
    errors,
  };
  console.log(JSON.stringify(result));
  process.exit(errors.length === 0 && indexed.contiguous ? 0 : 1);
}

await main();
