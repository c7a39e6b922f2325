//! The MCAP writer of the run log, written by hand (the `mcap` crate still reads logs, and
//! writes the files of `ehactl recover`).
//!
//! Why not the `mcap` crate's writer: it streams every message into the open chunk as ≈ 7
//! small writes (opcode, length, header fields, payload), each through two CRC writers and
//! an LZ4 frame encoder whose content checksum cannot be switched off (redundant with the
//! chunk's own CRC). That cost ≈ 1.3 µs of CPU per cycle record with LZ4 (≈ 0.7 µs
//! uncompressed), more than the control loop itself. mcap 0.26, the latest release
//! (checked 2026-11-26), has the same chunk writer, and no maintained Rust MCAP writer
//! buffers the chunk and compresses it once. This one does what the C++ reference writer
//! does: each message record is serialised straight into a reusable buffer (no CRC, no
//! compressor per write); when the chunk closes, its CRC-32 is computed in one pass, the
//! chunk is compressed in one call into one LZ4 frame (independent blocks of up to 4 MiB,
//! no block or content checksum: the chunk CRC covers the records; acceleration 2), and the Chunk record
//! and its Message Index records go to the file in a few large writes.
//!
//! File layout (MCAP format specification, <https://mcap.dev/spec>, major version 0):
//!
//! ```text
//! Magic Header Schema* Channel* Metadata* (Chunk MessageIndex*)* DataEnd
//! Schema* Channel* Statistics ChunkIndex* MetadataIndex* SummaryOffset* Footer Magic
//! ```
//!
//! Schemas, channels and metadata are top-level records of the data section, each in the
//! file before any message that uses it (a channel added mid-run, `/can`, is written ahead
//! of the open chunk). Messages live only in chunks. The data-section CRC (DataEnd) covers
//! every byte from the leading magic up to DataEnd; the summary CRC (Footer) every byte from
//! the start of the summary section through the Footer's two offsets. Files are checked by
//! the `mcap` crate's readers (tests below), the official Python reader and `@mcap/core`
//! (tests/python, tests/node).

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{self, Write};

/// Leading and trailing magic bytes of an MCAP file (major version 0).
pub const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

/// Record opcodes (MCAP spec, "Records").
mod op {
    pub const HEADER: u8 = 0x01;
    pub const FOOTER: u8 = 0x02;
    pub const SCHEMA: u8 = 0x03;
    pub const CHANNEL: u8 = 0x04;
    pub const MESSAGE: u8 = 0x05;
    pub const CHUNK: u8 = 0x06;
    pub const MESSAGE_INDEX: u8 = 0x07;
    pub const CHUNK_INDEX: u8 = 0x08;
    pub const STATISTICS: u8 = 0x0B;
    pub const METADATA: u8 = 0x0C;
    pub const METADATA_INDEX: u8 = 0x0D;
    pub const SUMMARY_OFFSET: u8 = 0x0E;
    pub const DATA_END: u8 = 0x0F;
}

/// Chunk compression.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compression {
    /// Records stored as they are (compression `""`).
    None,
    /// One LZ4 frame per chunk (compression `"lz4"`).
    Lz4,
}

impl Compression {
    fn name(self) -> &'static str {
        match self {
            Compression::None => "",
            Compression::Lz4 => "lz4",
        }
    }
}

fn put_u16(b: &mut Vec<u8>, v: u16) {
    b.extend_from_slice(&v.to_le_bytes());
}

fn put_u32(b: &mut Vec<u8>, v: u32) {
    b.extend_from_slice(&v.to_le_bytes());
}

fn put_u64(b: &mut Vec<u8>, v: u64) {
    b.extend_from_slice(&v.to_le_bytes());
}

fn too_long(what: &str, n: usize) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidInput,
        format!("{what} is {n} bytes; MCAP allows at most 4 GiB (u32 length)"),
    )
}

/// `u32` length prefix then the bytes (MCAP `String` and `Bytes` of schemas).
fn put_bytes32(b: &mut Vec<u8>, what: &str, s: &[u8]) -> io::Result<()> {
    let n = u32::try_from(s.len()).map_err(|_| too_long(what, s.len()))?;
    put_u32(b, n);
    b.extend_from_slice(s);
    Ok(())
}

fn put_str(b: &mut Vec<u8>, what: &str, s: &str) -> io::Result<()> {
    put_bytes32(b, what, s.as_bytes())
}

/// `Map<String, String>`: `u32` byte length of the entries, then key and value of each.
fn put_str_map(b: &mut Vec<u8>, what: &str, m: &BTreeMap<String, String>) -> io::Result<()> {
    let at = b.len();
    put_u32(b, 0);
    for (k, v) in m {
        put_str(b, what, k)?;
        put_str(b, what, v)?;
    }
    patch_len32(b, at, what)
}

/// Write the byte length of what follows the `u32` at `at` into it.
fn patch_len32(b: &mut [u8], at: usize, what: &str) -> io::Result<()> {
    let n = b.len() - at - 4;
    let n32 = u32::try_from(n).map_err(|_| too_long(what, n))?;
    b[at..at + 4].copy_from_slice(&n32.to_le_bytes());
    Ok(())
}

/// Start a record: opcode and a placeholder content length. Returns where the length is.
fn begin(b: &mut Vec<u8>, opcode: u8) -> usize {
    b.push(opcode);
    let at = b.len();
    put_u64(b, 0);
    at
}

/// End the record whose length is at `at` (see [`begin`]).
fn end(b: &mut [u8], at: usize) {
    let len = (b.len() - at - 8) as u64;
    b[at..at + 8].copy_from_slice(&len.to_le_bytes());
}

/// Append one record built by `body` to `b`; on error `b` is left as it was.
fn record(
    b: &mut Vec<u8>,
    opcode: u8,
    body: impl FnOnce(&mut Vec<u8>) -> io::Result<()>,
) -> io::Result<()> {
    let start = b.len();
    let at = begin(b, opcode);
    match body(b) {
        Ok(()) => {
            end(b, at);
            Ok(())
        }
        Err(e) => {
            b.truncate(start);
            Err(e)
        }
    }
}

/// Length of a Message record's fixed part after opcode and length: channel id (u16),
/// sequence (u32), log time (u64), publish time (u64).
const MESSAGE_HEADER: usize = 2 + 4 + 8 + 8;

/// An MCAP file being written. Call [`Writer::flush`] to close the open chunk and hand
/// everything so far to the OS, [`Writer::finish`] to write the summary and footer.
/// Nothing here allocates per message once the buffers have grown to one chunk.
pub struct Writer {
    file: File,
    /// Bytes handed to the file so far: the file offset of the next byte written.
    written: u64,
    /// Top-level records not yet written, in file order.
    pending: Vec<u8>,
    /// CRC-32 of every byte handed to the file so far (the data section, until `finish`).
    data_crc: crc32fast::Hasher,
    compression: Compression,
    /// A chunk is closed once its records reach this many bytes (uncompressed).
    chunk_limit: usize,
    /// Records of the open chunk, uncompressed.
    chunk: Vec<u8>,
    /// Log-time range (ns) of the open chunk's messages.
    chunk_times: Option<(u64, u64)>,
    /// Per channel id: (log time, offset in the chunk's records) of each message of the
    /// open chunk, for its Message Index record. Slot 0 is unused (ids start at 1).
    index: Vec<Vec<(u64, u64)>>,
    /// The LZ4 frame of the chunk being closed; kept at its largest size, `packed_len`
    /// bytes of it in use.
    packed: Vec<u8>,
    /// Schema and Channel records as written, repeated in the summary.
    schemas: Vec<u8>,
    schema_count: u16,
    channels: Vec<u8>,
    channel_count: u16,
    /// Messages per channel id (slot 0 unused).
    messages: Vec<u64>,
    /// Log-time range (ns) of every message so far.
    times: Option<(u64, u64)>,
    /// Chunk Index and Metadata Index records, for the summary.
    chunk_indexes: Vec<u8>,
    chunk_count: u32,
    metadata_indexes: Vec<u8>,
    metadata_count: u32,
}

impl Writer {
    /// Start an MCAP file on `file` (empty, positioned at 0): magic and Header record
    /// (`profile`, `library`). Nothing reaches the file before the first [`Writer::flush`].
    pub fn new(
        file: File,
        profile: &str,
        library: &str,
        compression: Compression,
        chunk_limit: usize,
    ) -> io::Result<Writer> {
        let mut pending = Vec::with_capacity(64 << 10);
        pending.extend_from_slice(MAGIC);
        record(&mut pending, op::HEADER, |b| {
            put_str(b, "profile", profile)?;
            put_str(b, "library", library)
        })?;
        Ok(Writer {
            file,
            written: 0,
            pending,
            data_crc: crc32fast::Hasher::new(),
            compression,
            chunk_limit: chunk_limit.max(1),
            chunk: Vec::new(),
            chunk_times: None,
            index: vec![Vec::new()],
            packed: Vec::new(),
            schemas: Vec::new(),
            schema_count: 0,
            channels: Vec::new(),
            channel_count: 0,
            messages: vec![0],
            times: None,
            chunk_indexes: Vec::new(),
            chunk_count: 0,
            metadata_indexes: Vec::new(),
            metadata_count: 0,
        })
    }

    /// Add a schema; returns its id (1, 2, … in call order).
    pub fn add_schema(&mut self, name: &str, encoding: &str, data: &[u8]) -> io::Result<u16> {
        let id = self
            .schema_count
            .checked_add(1)
            .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "too many schemas"))?;
        let start = self.pending.len();
        record(&mut self.pending, op::SCHEMA, |b| {
            put_u16(b, id);
            put_str(b, "schema name", name)?;
            put_str(b, "schema encoding", encoding)?;
            put_bytes32(b, "schema data", data)
        })?;
        self.schemas.extend_from_slice(&self.pending[start..]);
        self.schema_count = id;
        Ok(id)
    }

    /// Add a channel on schema `schema_id` (0: none); returns its id (1, 2, … in call order).
    pub fn add_channel(
        &mut self,
        schema_id: u16,
        topic: &str,
        message_encoding: &str,
        metadata: &BTreeMap<String, String>,
    ) -> io::Result<u16> {
        if schema_id > self.schema_count {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("channel {topic}: unknown schema id {schema_id}"),
            ));
        }
        let id = self
            .channel_count
            .checked_add(1)
            .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "too many channels"))?;
        let start = self.pending.len();
        record(&mut self.pending, op::CHANNEL, |b| {
            put_u16(b, id);
            put_u16(b, schema_id);
            put_str(b, "topic", topic)?;
            put_str(b, "message encoding", message_encoding)?;
            put_str_map(b, "channel metadata", metadata)
        })?;
        self.channels.extend_from_slice(&self.pending[start..]);
        self.channel_count = id;
        self.index.push(Vec::new());
        self.messages.push(0);
        Ok(id)
    }

    /// Write a Metadata record (top level; indexed in the summary).
    pub fn write_metadata(
        &mut self,
        name: &str,
        metadata: &BTreeMap<String, String>,
    ) -> io::Result<()> {
        let start = self.pending.len();
        let offset = self.written + start as u64;
        record(&mut self.pending, op::METADATA, |b| {
            put_str(b, "metadata name", name)?;
            put_str_map(b, "metadata", metadata)
        })?;
        let length = (self.pending.len() - start) as u64;
        record(&mut self.metadata_indexes, op::METADATA_INDEX, |b| {
            put_u64(b, offset);
            put_u64(b, length);
            put_str(b, "metadata name", name)
        })?;
        self.metadata_count += 1;
        Ok(())
    }

    /// Append a message to the open chunk (closing the chunk once it reaches the size limit).
    #[inline]
    pub fn write_message(
        &mut self,
        channel: u16,
        sequence: u32,
        log_time: u64,
        publish_time: u64,
        data: &[u8],
    ) -> io::Result<()> {
        self.write_message_with(channel, sequence, log_time, publish_time, |b| {
            b.extend_from_slice(data)
        })
    }

    /// Append a message whose payload `encode` appends to the buffer it is handed (the
    /// open chunk itself: the payload is serialised in place, not copied).
    #[inline]
    pub fn write_message_with(
        &mut self,
        channel: u16,
        sequence: u32,
        log_time: u64,
        publish_time: u64,
        encode: impl FnOnce(&mut Vec<u8>),
    ) -> io::Result<()> {
        let ch = usize::from(channel);
        if ch == 0 || ch > usize::from(self.channel_count) {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("message on unknown channel id {channel}"),
            ));
        }
        let offset = self.chunk.len();
        let mut h = [0u8; 9 + MESSAGE_HEADER];
        h[0] = op::MESSAGE;
        // h[1..9]: the record's length, written once the payload is in.
        h[9..11].copy_from_slice(&channel.to_le_bytes());
        h[11..15].copy_from_slice(&sequence.to_le_bytes());
        h[15..23].copy_from_slice(&log_time.to_le_bytes());
        h[23..31].copy_from_slice(&publish_time.to_le_bytes());
        self.chunk.extend_from_slice(&h);
        encode(&mut self.chunk);
        let len = (self.chunk.len() - offset - 9) as u64;
        self.chunk[offset + 1..offset + 9].copy_from_slice(&len.to_le_bytes());
        self.index[ch].push((log_time, offset as u64));
        self.messages[ch] += 1;
        let widen = |r: Option<(u64, u64)>| match r {
            None => (log_time, log_time),
            Some((a, b)) => (a.min(log_time), b.max(log_time)),
        };
        self.chunk_times = Some(widen(self.chunk_times));
        self.times = Some(widen(self.times));
        if self.chunk.len() >= self.chunk_limit {
            self.close_chunk()?;
        }
        Ok(())
    }

    /// Hand the pending top-level records to the file.
    fn write_pending(&mut self) -> io::Result<()> {
        if !self.pending.is_empty() {
            self.file.write_all(&self.pending)?;
            self.data_crc.update(&self.pending);
            self.written += self.pending.len() as u64;
            self.pending.clear();
        }
        Ok(())
    }

    /// Close the open chunk (if it holds any message): CRC, compression, Chunk record,
    /// Message Index records, Chunk Index entry.
    fn close_chunk(&mut self) -> io::Result<()> {
        let Some((start_time, end_time)) = self.chunk_times else {
            return Ok(());
        };
        let mut crc = crc32fast::Hasher::new();
        crc.update(&self.chunk);
        let uncompressed_crc = crc.clone().finalize();
        let uncompressed_size = self.chunk.len() as u64;
        let stored_len = match self.compression {
            Compression::None => self.chunk.len(),
            Compression::Lz4 => lz4_frame(&self.chunk, &mut self.packed)?,
        };
        let name = self.compression.name();
        let chunk_start = self.written + self.pending.len() as u64;
        let at = begin(&mut self.pending, op::CHUNK);
        put_u64(&mut self.pending, start_time);
        put_u64(&mut self.pending, end_time);
        put_u64(&mut self.pending, uncompressed_size);
        put_u32(&mut self.pending, uncompressed_crc);
        put_str(&mut self.pending, "compression", name)?;
        put_u64(&mut self.pending, stored_len as u64);
        // The record's content: the header fields above, then the stored records.
        let content = (self.pending.len() - at - 8 + stored_len) as u64;
        self.pending[at..at + 8].copy_from_slice(&content.to_le_bytes());
        self.write_pending()?;
        match self.compression {
            Compression::None => {
                self.file.write_all(&self.chunk)?;
                // Same bytes as the chunk CRC: extend the data CRC without a second pass.
                self.data_crc.combine(&crc);
            }
            Compression::Lz4 => {
                let stored = &self.packed[..stored_len];
                self.file.write_all(stored)?;
                self.data_crc.update(stored);
            }
        }
        self.written += stored_len as u64;
        let chunk_length = self.written - chunk_start;

        // Message Index records (one per channel with messages in this chunk, by id) and
        // this chunk's Chunk Index entry, which points at them.
        let ci = &mut self.chunk_indexes;
        let ci_at = begin(ci, op::CHUNK_INDEX);
        put_u64(ci, start_time);
        put_u64(ci, end_time);
        put_u64(ci, chunk_start);
        put_u64(ci, chunk_length);
        let map_at = ci.len();
        put_u32(ci, 0);
        let mi_start = self.pending.len();
        for (ch, entries) in self.index.iter_mut().enumerate().skip(1) {
            if entries.is_empty() {
                continue;
            }
            put_u16(ci, ch as u16);
            put_u64(ci, self.written + self.pending.len() as u64);
            let mi = &mut self.pending;
            let at = begin(mi, op::MESSAGE_INDEX);
            put_u16(mi, ch as u16);
            let n = entries.len() * 16;
            put_u32(
                mi,
                u32::try_from(n).map_err(|_| too_long("message index", n))?,
            );
            for &(t, off) in entries.iter() {
                put_u64(mi, t);
                put_u64(mi, off);
            }
            end(mi, at);
            entries.clear();
        }
        patch_len32(ci, map_at, "message index offsets")?;
        put_u64(ci, (self.pending.len() - mi_start) as u64);
        put_str(ci, "compression", name)?;
        put_u64(ci, stored_len as u64);
        put_u64(ci, uncompressed_size);
        end(ci, ci_at);
        self.chunk_count += 1;
        self.chunk.clear();
        self.chunk_times = None;
        Ok(())
    }

    /// Close the open chunk and hand everything written so far to the OS (a killed process
    /// leaves a file readable up to here; `ehactl recover` rebuilds its summary).
    pub fn flush(&mut self) -> io::Result<()> {
        self.close_chunk()?;
        self.write_pending()?;
        self.file.flush()
    }

    /// Close the open chunk, write DataEnd (data-section CRC), the summary section (schemas,
    /// channels, statistics, chunk and metadata indexes, summary offsets), the Footer
    /// (summary CRC) and the closing magic.
    pub fn finish(mut self) -> io::Result<()> {
        self.close_chunk()?;
        self.write_pending()?;
        let data_crc = self.data_crc.clone().finalize();
        let base = self.written;
        let mut s = std::mem::take(&mut self.pending);
        record(&mut s, op::DATA_END, |b| {
            put_u32(b, data_crc);
            Ok(())
        })?;
        let summary_at = s.len();
        let mut groups: Vec<(u8, u64, u64)> = Vec::new();
        let mut group = |s: &mut Vec<u8>, opcode: u8, bytes: &[u8]| {
            if !bytes.is_empty() {
                let start = base + s.len() as u64;
                s.extend_from_slice(bytes);
                groups.push((opcode, start, bytes.len() as u64));
            }
        };
        group(&mut s, op::SCHEMA, &self.schemas);
        group(&mut s, op::CHANNEL, &self.channels);
        let mut stats = Vec::new();
        let (t0, t1) = self.times.unwrap_or((0, 0));
        record(&mut stats, op::STATISTICS, |b| {
            put_u64(b, self.messages.iter().sum());
            put_u16(b, self.schema_count);
            put_u32(b, u32::from(self.channel_count));
            put_u32(b, 0); // attachments
            put_u32(b, self.metadata_count);
            put_u32(b, self.chunk_count);
            put_u64(b, t0);
            put_u64(b, t1);
            let at = b.len();
            put_u32(b, 0);
            for (ch, &n) in self.messages.iter().enumerate().skip(1) {
                if n > 0 {
                    put_u16(b, ch as u16);
                    put_u64(b, n);
                }
            }
            patch_len32(b, at, "channel message counts")
        })?;
        group(&mut s, op::STATISTICS, &stats);
        group(&mut s, op::CHUNK_INDEX, &self.chunk_indexes);
        group(&mut s, op::METADATA_INDEX, &self.metadata_indexes);
        let summary_offset_start = base + s.len() as u64;
        for (opcode, start, len) in groups {
            record(&mut s, op::SUMMARY_OFFSET, |b| {
                b.push(opcode);
                put_u64(b, start);
                put_u64(b, len);
                Ok(())
            })?;
        }
        // Footer: its summary CRC covers the summary section and the Footer up to itself.
        s.push(op::FOOTER);
        put_u64(&mut s, 8 + 8 + 4);
        put_u64(&mut s, base + summary_at as u64);
        put_u64(&mut s, summary_offset_start);
        let summary_crc = crc32fast::hash(&s[summary_at..]);
        put_u32(&mut s, summary_crc);
        s.extend_from_slice(MAGIC);
        self.file.write_all(&s)?;
        self.file.flush()
    }
}

/// LZ4 frame format (lz4 `doc/lz4_Frame_format.md`): magic number, little endian.
const LZ4_FRAME_MAGIC: u32 = 0x184D_2204;
/// FLG byte: version 01, independent blocks, no block checksum, no content size, no
/// content checksum, no dictionary id.
const LZ4_FLG: u8 = 0b0110_0000;
/// BD byte: block maximum size 4 MiB (code 7).
const LZ4_BD: u8 = 0b0111_0000;
/// Largest uncompressed block of the frame (BD code 7).
const LZ4_BLOCK_MAX: usize = 4 << 20;
/// Header checksum: second byte of the XXH32 (seed 0) of the frame descriptor (FLG, BD).
const LZ4_HC: u8 = (xxh32_short(&[LZ4_FLG, LZ4_BD], 0) >> 8) as u8;
/// High bit of a block size: the block is stored uncompressed.
const LZ4_RAW_BLOCK: u32 = 0x8000_0000;
/// LZ4 acceleration (1 = `LZ4_compress_default`; higher skips faster over bytes that find no
/// match). On run-shaped records (`logger_throughput 100000 lz4`, 7 interleaved runs,
/// 2026-11-26): 1 → 0.64 µs writer CPU per record at 248.0 B/record, 2 → 0.47 µs at
/// 249.6 B (+0.6 %), 3 → 0.43 µs at 253.9 B, 6 → 0.43 µs at 280.7 B: 2 buys most of the
/// speed for almost no size.
const LZ4_ACCELERATION: i32 = 2;

/// XXH32 of an input shorter than 16 bytes (no stripe loop), for the LZ4 header checksum.
const fn xxh32_short(input: &[u8], seed: u32) -> u32 {
    const P1: u32 = 0x9E37_79B1;
    const P2: u32 = 0x85EB_CA77;
    const P3: u32 = 0xC2B2_AE3D;
    const P4: u32 = 0x27D4_EB2F;
    const P5: u32 = 0x1656_67B1;
    assert!(input.len() < 16);
    let mut h = seed.wrapping_add(P5).wrapping_add(input.len() as u32);
    let mut i = 0;
    while i + 4 <= input.len() {
        let w = u32::from_le_bytes([input[i], input[i + 1], input[i + 2], input[i + 3]]);
        h = h
            .wrapping_add(w.wrapping_mul(P3))
            .rotate_left(17)
            .wrapping_mul(P4);
        i += 4;
    }
    while i < input.len() {
        h = h
            .wrapping_add((input[i] as u32).wrapping_mul(P5))
            .rotate_left(11)
            .wrapping_mul(P1);
        i += 1;
    }
    h ^= h >> 15;
    h = h.wrapping_mul(P2);
    h ^= h >> 13;
    h = h.wrapping_mul(P3);
    h ^= h >> 16;
    h
}

/// Compress `src` into one LZ4 frame in `out` (grown as needed, never shrunk, so that it is
/// allocated and zeroed once); returns the frame's length. One block-compression call per
/// 4 MiB of input (one per chunk here); a block that does not shrink is stored raw.
fn lz4_frame(src: &[u8], out: &mut Vec<u8>) -> io::Result<usize> {
    let mut need = 7 + 4;
    for piece in src.chunks(LZ4_BLOCK_MAX) {
        need += 4 + lz4::block::compress_bound(piece.len())?;
    }
    if out.len() < need {
        out.resize(need, 0);
    }
    out[0..4].copy_from_slice(&LZ4_FRAME_MAGIC.to_le_bytes());
    out[4] = LZ4_FLG;
    out[5] = LZ4_BD;
    out[6] = LZ4_HC;
    let mut n = 7;
    for piece in src.chunks(LZ4_BLOCK_MAX) {
        let bound = lz4::block::compress_bound(piece.len())?;
        let dst = &mut out[n + 4..n + 4 + bound];
        let mode = Some(lz4::block::CompressionMode::FAST(LZ4_ACCELERATION));
        let packed = lz4::block::compress_to_buffer(piece, mode, false, dst)?;
        let size = if packed < piece.len() {
            packed as u32
        } else {
            dst[..piece.len()].copy_from_slice(piece);
            piece.len() as u32 | LZ4_RAW_BLOCK
        };
        out[n..n + 4].copy_from_slice(&size.to_le_bytes());
        n += 4 + (size & !LZ4_RAW_BLOCK) as usize;
    }
    out[n..n + 4].copy_from_slice(&0u32.to_le_bytes()); // end mark
    Ok(n + 4)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Read;
    use std::path::Path;

    /// A directory of one test's own, removed when the test ends (passed or not).
    struct TmpDir(std::path::PathBuf);

    impl TmpDir {
        fn new(test: &str) -> TmpDir {
            let dir =
                std::env::temp_dir().join(format!("ehactl_mcapw_{}_{test}", std::process::id()));
            std::fs::create_dir_all(&dir).unwrap();
            TmpDir(dir)
        }

        fn path(&self, name: &str) -> std::path::PathBuf {
            self.0.join(name)
        }
    }

    impl Drop for TmpDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    /// Pseudo-random bytes (an LCG), so LZ4 has something that does not compress.
    fn noise(n: usize, seed: u64) -> Vec<u8> {
        let mut s = seed;
        (0..n)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (s >> 56) as u8
            })
            .collect()
    }

    fn lz4_decode(frame: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        lz4::Decoder::new(frame)
            .unwrap()
            .read_to_end(&mut out)
            .unwrap();
        out
    }

    #[test]
    fn xxh32_gives_the_header_checksum_of_the_common_lz4_frame() {
        // Every frame of the `lz4` command line tool starts 04 22 4D 18 64 40 A7: FLG 0x64
        // (content checksum), BD 0x40 (64 KiB blocks), header checksum 0xA7.
        assert_eq!((xxh32_short(&[0x64, 0x40], 0) >> 8) as u8, 0xA7);
        // XXH32 of the empty input, seed 0 (xxHash's published test value).
        assert_eq!(xxh32_short(&[], 0), 0x02CC_5D05);
    }

    #[test]
    fn frame_header_is_the_one_liblz4_writes_for_these_settings() {
        let mut enc = lz4::EncoderBuilder::new()
            .block_size(lz4::BlockSize::Max4MB)
            .block_mode(lz4::BlockMode::Independent)
            .checksum(lz4::ContentChecksum::NoChecksum)
            .block_checksum(lz4::liblz4::BlockChecksum::NoBlockChecksum)
            .build(Vec::new())
            .unwrap();
        enc.write_all(b"x").unwrap();
        let (theirs, r) = enc.finish();
        r.unwrap();
        let mut ours = Vec::new();
        let n = lz4_frame(b"x", &mut ours).unwrap();
        assert_eq!(&ours[..7], &theirs[..7]);
        assert_eq!(lz4_decode(&ours[..n]), b"x");
    }

    #[test]
    fn lz4_frames_decode_to_their_input() {
        let mut out = Vec::new();
        // Compressible, incompressible (stored raw), several blocks, one byte.
        let text: Vec<u8> = (0..300_000u32)
            .flat_map(|i| (i % 977).to_le_bytes())
            .collect();
        let cases = [
            text.clone(),
            noise(100_000, 1),
            [noise(LZ4_BLOCK_MAX + 10, 2), text.clone()].concat(),
            vec![7u8],
        ];
        for c in &cases {
            let n = lz4_frame(c, &mut out).unwrap();
            assert_eq!(lz4_decode(&out[..n]), *c, "{} bytes", c.len());
        }
        let n = lz4_frame(&cases[1], &mut out).unwrap();
        // Raw block: header, size word with the high bit, data, end mark.
        assert_eq!(n, 7 + 4 + 100_000 + 4);
        assert_eq!(
            u32::from_le_bytes(out[7..11].try_into().unwrap()),
            100_000 | LZ4_RAW_BLOCK
        );
    }

    /// One message as the reference (the `mcap` crate's writer) and this writer are given it.
    struct Msg {
        topic: usize,
        seq: u32,
        t: u64,
        data: Vec<u8>,
    }

    fn messages() -> Vec<Msg> {
        let mut v = Vec::new();
        for k in 0..20_000u64 {
            let t = k * 200_000;
            v.push(Msg {
                topic: 0,
                seq: k as u32,
                t,
                data: noise(140, k).iter().map(|b| b & 0x0F).collect(),
            });
            v.push(Msg {
                topic: 1,
                seq: k as u32,
                t,
                data: noise(133, !k),
            });
            if k % 5000 == 0 {
                v.push(Msg {
                    topic: 2,
                    seq: (k / 5000) as u32,
                    t,
                    data: format!("{{\"k\": {k}}}").into_bytes(),
                });
            }
        }
        // A message on a channel added after the others were in use, out of time order.
        v.push(Msg {
            topic: 3,
            seq: 0,
            t: 5,
            data: b"{}".to_vec(),
        });
        v
    }

    const TOPICS: [(&str, &str, &str, &str); 4] = [
        ("/a", "pkg/msg/A", "ros2msg", "cdr"),
        ("/b", "pkg/msg/B", "ros2msg", "cdr"),
        ("/j", "J", "jsonschema", "json"),
        ("/late", "L", "jsonschema", "json"),
    ];

    fn ours(path: &Path, compression: Compression, msgs: &[Msg]) {
        let file = File::create(path).unwrap();
        let mut w = Writer::new(file, "ros2", "test", compression, 1 << 20).unwrap();
        let mut ch = Vec::new();
        for (topic, schema, enc, menc) in &TOPICS[..3] {
            let s = w.add_schema(schema, enc, schema.as_bytes()).unwrap();
            ch.push(w.add_channel(s, topic, menc, &BTreeMap::new()).unwrap());
        }
        let md = BTreeMap::from([("k".to_string(), "v".to_string())]);
        w.write_metadata("run", &md).unwrap();
        for (i, m) in msgs.iter().enumerate() {
            if m.topic == 3 && ch.len() == 3 {
                let (topic, schema, enc, menc) = TOPICS[3];
                let s = w.add_schema(schema, enc, schema.as_bytes()).unwrap();
                ch.push(w.add_channel(s, topic, menc, &md).unwrap());
            }
            w.write_message(ch[m.topic], m.seq, m.t, m.t, &m.data)
                .unwrap();
            if i % 1000 == 999 {
                w.flush().unwrap();
            }
        }
        w.finish().unwrap();
    }

    fn reference(path: &Path, compression: Compression, msgs: &[Msg]) {
        let file = std::io::BufWriter::new(File::create(path).unwrap());
        let mut w = mcap::WriteOptions::new()
            .compression(match compression {
                Compression::None => None,
                Compression::Lz4 => Some(mcap::Compression::Lz4),
            })
            .profile("ros2")
            .library("test")
            .chunk_size(Some(1 << 20))
            .create(file)
            .unwrap();
        let mut ch = Vec::new();
        for (topic, schema, enc, menc) in &TOPICS[..3] {
            let s = w.add_schema(schema, enc, schema.as_bytes()).unwrap();
            ch.push(w.add_channel(s, topic, menc, &BTreeMap::new()).unwrap());
        }
        let md = BTreeMap::from([("k".to_string(), "v".to_string())]);
        w.write_metadata(&mcap::records::Metadata {
            name: "run".into(),
            metadata: md.clone(),
        })
        .unwrap();
        for (i, m) in msgs.iter().enumerate() {
            if m.topic == 3 && ch.len() == 3 {
                let (topic, schema, enc, menc) = TOPICS[3];
                let s = w.add_schema(schema, enc, schema.as_bytes()).unwrap();
                ch.push(w.add_channel(s, topic, menc, &md).unwrap());
            }
            let h = mcap::records::MessageHeader {
                channel_id: ch[m.topic],
                sequence: m.seq,
                log_time: m.t,
                publish_time: m.t,
            };
            w.write_to_known_channel(&h, &m.data).unwrap();
            if i % 1000 == 999 {
                w.flush().unwrap();
            }
        }
        w.finish().unwrap();
    }

    /// (topic, schema name, sequence, log time, publish time, data) of every message, in file
    /// order, read by the `mcap` crate's linear reader (which checks chunk CRCs).
    type Seen = Vec<(String, String, u32, u64, u64, Vec<u8>)>;

    fn stream(bytes: &[u8]) -> Seen {
        mcap::MessageStream::new(bytes)
            .unwrap()
            .map(|m| {
                let m = m.unwrap();
                let schema = m.channel.schema.as_ref().map(|s| s.name.clone());
                (
                    m.channel.topic.clone(),
                    schema.unwrap_or_default(),
                    m.sequence,
                    m.log_time,
                    m.publish_time,
                    m.data.into_owned(),
                )
            })
            .collect()
    }

    #[test]
    fn files_read_back_like_the_mcap_crate_writers_own() {
        let msgs = messages();
        let dir = TmpDir::new("crate_writer");
        for compression in [Compression::Lz4, Compression::None] {
            let a = dir.path(&format!("ours_{compression:?}.mcap"));
            let b = dir.path(&format!("ref_{compression:?}.mcap"));
            ours(&a, compression, &msgs);
            reference(&b, compression, &msgs);
            let (a, b) = (std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
            let seen = stream(&a);
            assert_eq!(seen.len(), msgs.len());
            assert_eq!(seen, stream(&b), "{compression:?}");

            // Every record of the file, summary section included, as the crate's linear
            // reader walks it (the Python bindings' `read_mcap` does this for the header
            // and metadata).
            let mut kinds = BTreeMap::new();
            for r in mcap::read::LinearReader::new(&a).unwrap() {
                let name = match r.unwrap() {
                    mcap::records::Record::Header(h) => {
                        assert_eq!((h.profile.as_str(), h.library.as_str()), ("ros2", "test"));
                        "header"
                    }
                    mcap::records::Record::Metadata(_) => "metadata",
                    mcap::records::Record::DataEnd(_) => "data end",
                    mcap::records::Record::Footer(_) => "footer",
                    mcap::records::Record::Statistics(_) => "statistics",
                    _ => "other",
                };
                *kinds.entry(name).or_insert(0) += 1;
            }
            for k in ["header", "metadata", "data end", "footer", "statistics"] {
                assert_eq!(kinds.get(k), Some(&1), "{k}: {kinds:?}");
            }

            // The summary (footer, summary offsets) as the crate reads it.
            let sa = mcap::Summary::read(&a).unwrap().expect("a summary");
            let sb = mcap::Summary::read(&b).unwrap().unwrap();
            let (st_a, st_b) = (sa.stats.clone().unwrap(), sb.stats.clone().unwrap());
            assert_eq!(st_a.message_count, msgs.len() as u64);
            assert_eq!(st_a.channel_message_counts, st_b.channel_message_counts);
            assert_eq!(
                (st_a.message_start_time, st_a.message_end_time),
                (st_b.message_start_time, st_b.message_end_time)
            );
            assert_eq!(
                (st_a.schema_count, st_a.channel_count, st_a.metadata_count),
                (4, 4, 1)
            );
            assert_eq!(st_a.chunk_count as usize, sa.chunk_indexes.len());
            let topics = |s: &mcap::Summary| {
                let mut t: Vec<_> = s
                    .channels
                    .values()
                    .map(|c| {
                        (
                            c.id,
                            c.topic.clone(),
                            c.schema.as_ref().unwrap().name.clone(),
                        )
                    })
                    .collect();
                t.sort();
                t
            };
            assert_eq!(topics(&sa), topics(&sb));
            assert_eq!(sa.metadata_indexes.len(), 1);
            let md = mcap::read::metadata(&a, &sa.metadata_indexes[0]).unwrap();
            assert_eq!((md.name.as_str(), md.metadata["k"].as_str()), ("run", "v"));

            // Seeking through the chunk indexes and message indexes finds every message.
            let mut via_index = Vec::new();
            for ci in &sa.chunk_indexes {
                let idx = sa.read_message_indexes(&a, ci).unwrap();
                let mut offsets: Vec<u64> = idx.values().flatten().map(|e| e.offset).collect();
                offsets.sort();
                let mut n = 0;
                for m in sa.stream_chunk(&a, ci).unwrap() {
                    let m = m.unwrap();
                    assert!(
                        m.log_time >= ci.message_start_time && m.log_time <= ci.message_end_time
                    );
                    via_index.push((m.channel.topic.clone(), m.sequence, m.log_time));
                    n += 1;
                }
                assert_eq!(offsets.len(), n, "one index entry per message");
                // Seeking decompresses the chunk up to the entry: a few entries per channel.
                for (ch, entries) in &idx {
                    for e in [
                        &entries[0],
                        &entries[entries.len() / 2],
                        &entries[entries.len() - 1],
                    ] {
                        let m = sa.seek_message(&a, ci, e).unwrap();
                        assert_eq!((m.channel.id, m.log_time), (ch.id, e.log_time));
                    }
                }
            }
            let linear: Vec<_> = seen
                .iter()
                .map(|(t, _, s, lt, _, _)| (t.clone(), *s, *lt))
                .collect();
            assert_eq!(via_index, linear);
        }
    }

    #[test]
    fn crcs_are_checked_by_the_reader_and_match_the_bytes() {
        let msgs: Vec<Msg> = messages().into_iter().take(3000).collect();
        let dir = TmpDir::new("crc");
        let a = dir.path("crc.mcap");
        ours(&a, Compression::Lz4, &msgs);
        let bytes = std::fs::read(&a).unwrap();
        // Footer: summary start, summary offset start, summary CRC; then the magic.
        let f = bytes.len() - 8 - 20;
        let summary_start = u64::from_le_bytes(bytes[f..f + 8].try_into().unwrap()) as usize;
        let summary_crc = u32::from_le_bytes(bytes[f + 16..f + 20].try_into().unwrap());
        assert_eq!(crc32fast::hash(&bytes[summary_start..f + 16]), summary_crc);
        // DataEnd (opcode 0x0F, length 4) sits just before the summary; its CRC covers the
        // file up to it.
        let d = summary_start - 13;
        assert_eq!(bytes[d], 0x0F);
        let data_crc = u32::from_le_bytes(bytes[d + 9..d + 13].try_into().unwrap());
        assert_eq!(crc32fast::hash(&bytes[..d]), data_crc);
        assert_ne!(data_crc, 0);
        // A flipped byte in a chunk's stored records is caught by the reader.
        let sa = mcap::Summary::read(&bytes).unwrap().unwrap();
        let ci = &sa.chunk_indexes[0];
        let mut bad = bytes.clone();
        bad[(ci.chunk_start_offset + ci.chunk_length - ci.compressed_size / 2) as usize] ^= 0x10;
        assert!(mcap::MessageStream::new(&bad).unwrap().any(|m| m.is_err()));
    }

    #[test]
    fn a_file_cut_after_a_flush_is_recoverable() {
        let msgs: Vec<Msg> = messages().into_iter().take(2500).collect();
        let dir = TmpDir::new("cut");
        let a = dir.path("cut.mcap");
        let file = File::create(&a).unwrap();
        let mut w = Writer::new(file, "ros2", "test", Compression::Lz4, 1 << 20).unwrap();
        let s = w.add_schema("S", "jsonschema", b"{}").unwrap();
        let c = w.add_channel(s, "/x", "json", &BTreeMap::new()).unwrap();
        for m in &msgs[..2000] {
            w.write_message(c, m.seq, m.t, m.t, b"{}").unwrap();
        }
        w.flush().unwrap();
        for m in &msgs[2000..] {
            w.write_message(c, m.seq, m.t, m.t, b"{}").unwrap();
        }
        drop(w); // killed: the open chunk, the summary and the footer never reach the file
        let out = dir.path("cut_recovered.mcap");
        let rep = crate::recover::recover(&a, &out).unwrap();
        assert_eq!(rep.count("/x"), 2000);
        assert!(!rep.was_complete);
    }
}
