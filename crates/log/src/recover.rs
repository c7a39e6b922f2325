//! `ehactl recover`: rebuild a valid, indexed MCAP file from a log whose writer was killed
//! (SIGKILL, power loss, full disk) before it wrote the summary section and footer, or whose
//! bytes were damaged on the way (a bad sector, a flipped bit, a copy cut short).
//!
//! The damaged file is walked record by record with the MCAP framing (opcode, `u64` length,
//! body; MCAP specification <https://mcap.dev/spec>, "Records"). Every schema, channel and
//! metadata record and every message of every chunk that checks out (sizes consistent,
//! decompresses to its claimed size, CRC, every inner record well framed and parsed) is
//! copied, in order, into a new file written by the `mcap` crate (chunk CRCs, message and
//! chunk indexes, statistics, summary, footer). A bad chunk is skipped and counted, whole: a
//! chunk is taken whole or not at all. When a chunk's own length cannot be trusted, reading
//! resumes at the next chunk: from the chunk index of the summary section when the file has
//! one (a complete file), otherwise at the next byte offset where a chunk record's framing is
//! self-consistent (its length equals its header fields plus its stored records). Chunks
//! may be uncompressed, `lz4` or `zstd`, the compressions the specification names; any
//! other is reported as unreadable, by name. The official readers do none of this (they
//! refuse a file without a footer, or stop at the first bad record), hence this module.

use mcap::read::parse_record;
use mcap::records::{MessageHeader, Metadata, Record};
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

/// What a recovery found and kept.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RecoverReport {
    /// Messages copied, per topic.
    pub messages: BTreeMap<String, u64>,
    /// Chunks copied (every message of each).
    pub chunks: u64,
    /// Chunks dropped because their sizes, compression, CRC or contents were bad (each
    /// reason in `problems`).
    pub bad_chunks: u64,
    /// Chunks listed by the chunk index of the summary section, when the file has a
    /// readable one (a complete file); `None` for a cut-off file.
    pub chunks_indexed: Option<u64>,
    /// Bytes of the data section that could not be read as records (corrupt framing),
    /// skipped to find the next chunk.
    pub skipped_bytes: u64,
    /// Messages from intact chunks whose channel record was lost (not decodable, not copied).
    pub messages_without_channel: u64,
    /// What was dropped or skipped and why, with byte offsets, in file order.
    pub problems: Vec<String>,
    /// The file ends inside a record (cut off).
    pub stopped_early: bool,
    /// The input already had a valid footer.
    pub was_complete: bool,
    /// Log time of the last recovered message (s).
    pub last_time_s: f64,
}

impl RecoverReport {
    /// Messages copied on `topic`.
    pub fn count(&self, topic: &str) -> u64 {
        self.messages.get(topic).copied().unwrap_or(0)
    }

    /// Messages copied, all topics.
    pub fn total_messages(&self) -> u64 {
        self.messages.values().sum()
    }
}

struct Schema {
    name: String,
    encoding: String,
    data: Vec<u8>,
}

struct Channel {
    schema_id: u16,
    topic: String,
    encoding: String,
    metadata: BTreeMap<String, String>,
}

/// Largest decompression ratio accepted for an LZ4 chunk (LZ4's format limit is ≈ 255:1).
/// A chunk header claiming more is corrupt.
const MAX_LZ4_RATIO: u64 = 256;

/// Largest uncompressed chunk read (bytes): 1 000 MB. A reader holds one chunk at a time
/// (decompressed, and its records while they are handed on), so this bounds what a chunk
/// costs whatever its header claims. The MCAP writers cut chunks at a target size (ehactl's
/// logger at 1 MiB, `CHUNK_LIMIT` in `crates/log/src/logger.rs`; the official Python writer
/// at 1 MiB, the official Rust writer at 768 KiB by default); only a single larger message
/// makes a larger chunk. Zstandard has no fixed ratio limit (a
/// 10 MB string of one repeated character compresses to a few kB), so the declared size is
/// checked against this limit, not against the stored size.
pub const MAX_CHUNK_BYTES: u64 = 1_000_000_000;

/// Whether a chunk's claimed uncompressed size is possible for its stored size and within
/// [`MAX_CHUNK_BYTES`]. The `mcap` crate (0.24) allocates the claimed size before
/// decompressing, so a corrupt header would abort the process with an allocation failure
/// (found by tests/rust/fuzz_parsers.rs): every chunk is checked here first. An unknown
/// compression is not plausible.
pub fn chunk_size_plausible(compression: &str, uncompressed: u64, stored: u64) -> bool {
    uncompressed <= MAX_CHUNK_BYTES
        && match compression {
            "" => uncompressed == stored,
            "lz4" => uncompressed <= stored.saturating_mul(MAX_LZ4_RATIO).saturating_add(4096),
            "zstd" => true,
            _ => false,
        }
}

fn u64_at(b: &[u8], at: usize) -> Option<u64> {
    b.get(at..at.checked_add(8)?)
        .map(|s| u64::from_le_bytes(s.try_into().unwrap()))
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    b.get(at..at.checked_add(4)?)
        .map(|s| u32::from_le_bytes(s.try_into().unwrap()))
}

/// Opcode of a Chunk record (MCAP spec, "Chunk (op=0x06)").
const OP_CHUNK: u8 = 0x06;
const OP_FOOTER: u8 = 0x02;
const OP_DATA_END: u8 = 0x0F;

/// The fields of a Chunk record's body, checked for consistency: the body is exactly its
/// header (start and end time, uncompressed size, CRC, compression string, stored size) and
/// the stored records.
struct ChunkHeader<'a> {
    uncompressed: u64,
    crc: u32,
    compression: &'a str,
    records: &'a [u8],
}

fn chunk_header(body: &[u8]) -> Result<ChunkHeader<'_>, String> {
    let bad = || "chunk header cut off or inconsistent".to_string();
    let uncompressed = u64_at(body, 16).ok_or_else(bad)?;
    let crc = u32_at(body, 24).ok_or_else(bad)?;
    let clen = u32_at(body, 28).ok_or_else(bad)? as usize;
    let cend = 32usize.checked_add(clen).ok_or_else(bad)?;
    let compression = body
        .get(32..cend)
        .and_then(|c| std::str::from_utf8(c).ok())
        .ok_or_else(bad)?;
    let stored = u64_at(body, cend).ok_or_else(bad)?;
    let rec_start = cend + 8;
    if usize::try_from(stored).ok() != Some(body.len() - rec_start.min(body.len()))
        || rec_start > body.len()
    {
        return Err(format!(
            "chunk length {} disagrees with its header ({} stored bytes after a {rec_start}-byte header)",
            body.len(),
            stored
        ));
    }
    Ok(ChunkHeader {
        uncompressed,
        crc,
        compression,
        records: &body[rec_start..],
    })
}

/// Decompress a chunk body (bounded by its plausible claimed size), check its CRC when it
/// has one, and walk its records: every record length must fit and every record must parse.
/// Returns the records.
fn read_chunk(body: &[u8]) -> Result<Vec<Record<'static>>, String> {
    let plain = chunk_plain(body)?;
    let mut out = Vec::new();
    chunk_records(&plain, |rec| {
        out.push(rec.into_owned());
        Ok(())
    })?;
    Ok(out)
}

/// The records of a chunk body, decompressed (bounded by its declared size, at most
/// [`MAX_CHUNK_BYTES`]) and CRC-checked when the chunk has a CRC.
pub(crate) fn chunk_plain(body: &[u8]) -> Result<std::borrow::Cow<'_, [u8]>, String> {
    use std::io::Read;
    let h = chunk_header(body)?;
    let stored = h.records.len() as u64;
    let (u, c) = (h.uncompressed, h.compression);
    match c {
        "" | "lz4" | "zstd" => {}
        other => {
            return Err(format!(
                "compression `{other}` is not one the MCAP specification names (none, lz4, zstd); ehactl cannot read it"
            ))
        }
    }
    if !chunk_size_plausible(c, u, stored) {
        return Err(format!(
            "claims {u} bytes uncompressed from {stored} bytes of `{}` (at most {MAX_CHUNK_BYTES} bytes are read per chunk)",
            if c.is_empty() { "none" } else { c }
        ));
    }
    let bounded = |r: &mut dyn Read, what: &str| -> Result<Vec<u8>, String> {
        // Reserved up to a few times the stored size only: a false claim costs what
        // decompression really produces, not what the header says.
        let mut out = Vec::with_capacity(u.min(stored.saturating_mul(8).max(1 << 16)) as usize);
        r.take(u + 1)
            .read_to_end(&mut out)
            .map_err(|e| format!("{what}: {e}"))?;
        Ok(out)
    };
    let plain = match c {
        "lz4" => {
            let mut dec = lz4::Decoder::new(h.records).map_err(|e| format!("lz4: {e}"))?;
            std::borrow::Cow::Owned(bounded(&mut dec, "lz4")?)
        }
        "zstd" => {
            let mut dec =
                zstd::stream::read::Decoder::new(h.records).map_err(|e| format!("zstd: {e}"))?;
            std::borrow::Cow::Owned(bounded(&mut dec, "zstd")?)
        }
        _ => std::borrow::Cow::Borrowed(h.records),
    };
    if plain.len() as u64 != u {
        return Err(format!(
            "decompresses to {} bytes, its header says {u}",
            plain.len()
        ));
    }
    if h.crc != 0 && crc32fast::hash(&plain) != h.crc {
        return Err("CRC mismatch".into());
    }
    Ok(plain)
}

/// Hand every record of a decompressed chunk to `f`, in order: every record length must
/// fit and every record must parse.
pub(crate) fn chunk_records<'a>(
    plain: &'a [u8],
    mut f: impl FnMut(Record<'a>) -> Result<(), String>,
) -> Result<(), String> {
    let mut p = 0usize;
    while p < plain.len() {
        let op = plain[p];
        let len = u64_at(plain, p + 1)
            .ok_or_else(|| format!("inner record at byte {p}: header cut off"))?;
        let end = usize::try_from(len)
            .ok()
            .and_then(|l| (p + 9).checked_add(l))
            .filter(|&e| e <= plain.len())
            .ok_or_else(|| {
                format!("inner record at byte {p} claims {len} bytes, beyond the chunk")
            })?;
        let rec = parse_record(op, &plain[p + 9..end])
            .map_err(|e| format!("inner record at byte {p} (opcode {op:#04x}): {e}"))?;
        f(rec)?;
        p = end;
    }
    Ok(())
}

/// Walk the top-level records of an MCAP file (opcode, length, body) without parsing
/// message contents. Returns the length of the well-formed prefix (magic plus whole records
/// whose lengths fit in the file and whose chunks check out: sizes, decompression, CRC,
/// inner framing) and, if the walk stopped early, why. The `mcap` crate (0.24) reserves a
/// record's claimed length before checking it against the data, so a corrupt length field
/// would abort the process with an allocation failure (found by tests/rust/fuzz_parsers.rs):
/// only this prefix may be handed to it.
pub fn readable_prefix(data: &[u8]) -> (usize, Option<String>) {
    if data.len() < 8 || &data[..8] != mcap::MAGIC {
        return (0, Some("does not start with the MCAP magic bytes".into()));
    }
    let mut pos = 8usize; // after the magic
    loop {
        if pos == data.len() {
            return (pos, None);
        }
        let (op, body_end) = match frame_at(data, pos) {
            Ok(v) => v,
            Err(why) => return (pos, Some(why)),
        };
        if op == OP_CHUNK {
            if let Err(why) = read_chunk(&data[pos + 9..body_end]) {
                return (pos, Some(format!("corrupt chunk at byte {pos}: {why}")));
            }
        }
        pos = body_end;
        if op == OP_FOOTER {
            // Footer: the magic follows.
            return (data.len().min(pos + 8), None);
        }
    }
}

/// Opcode and end of the record at `pos`, if its header and claimed length fit in `data`.
fn frame_at(data: &[u8], pos: usize) -> Result<(u8, usize), String> {
    if pos + 9 > data.len() {
        return Err(format!("cut off at byte {pos} (a record header)"));
    }
    let len = u64_at(data, pos + 1).unwrap_or(u64::MAX);
    usize::try_from(len)
        .ok()
        .and_then(|l| (pos + 9).checked_add(l))
        .filter(|&e| e <= data.len())
        .map(|e| (data[pos], e))
        .ok_or_else(|| {
            format!(
                "record at byte {pos} claims {len} bytes; only {} remain (cut off or corrupt)",
                data.len() - pos - 9
            )
        })
}

/// Whether a Chunk record with self-consistent framing starts at `pos` (its length fits in
/// the file and equals its header plus its stored bytes, with a compression name the
/// specification knows): where reading resumes after corrupt bytes.
fn chunk_frame_at(data: &[u8], pos: usize) -> Option<usize> {
    chunk_framed(data, pos)
        .filter(|&(_, known)| known)
        .map(|(end, _)| end)
}

/// End of the Chunk record at `pos` if its framing is self-consistent, and whether its
/// compression is one the specification names.
fn chunk_framed(data: &[u8], pos: usize) -> Option<(usize, bool)> {
    if data.get(pos) != Some(&OP_CHUNK) {
        return None;
    }
    let (_, end) = frame_at(data, pos).ok()?;
    let h = chunk_header(&data[pos + 9..end]).ok()?;
    Some((end, matches!(h.compression, "" | "lz4" | "zstd")))
}

/// Opcodes of the data section's records outside chunks that reading may resume at after
/// corrupt bytes (MCAP spec: Schema 0x03, Channel 0x04, Message 0x05, Message Index 0x07,
/// Attachment 0x09, Metadata 0x0C, Data End 0x0F).
const RESYNC_OPS: [u8; 7] = [0x03, 0x04, 0x05, 0x07, 0x09, 0x0C, OP_DATA_END];

/// Whether a record outside a chunk starts at `pos`: an opcode of [`RESYNC_OPS`], a length
/// that fits in `data`, a body that parses, and after it the end of `data` or the header of
/// a record whose length fits too (a random byte rarely passes all three).
fn record_frame_at(data: &[u8], pos: usize) -> bool {
    let op = data[pos];
    if !RESYNC_OPS.contains(&op) {
        return false;
    }
    let Ok((_, end)) = frame_at(data, pos) else {
        return false;
    };
    if op != OP_DATA_END && parse_record(op, &data[pos + 9..end]).is_err() {
        return false;
    }
    end == data.len()
        || chunk_frame_at(data, end).is_some()
        || (RESYNC_OPS.contains(&data[end]) || data[end] == OP_FOOTER)
            && frame_at(data, end).is_ok()
}

/// Whether the end `end` of a record that parsed is a place a record can start: the end of
/// the data section, a record whose opcode the specification knows (or a private one,
/// 0x80–0xFF) and whose length fits, or, in a file cut off while being written, a known
/// opcode whose record the cut ends inside.
fn follows_ok(data: &[u8], limit: usize, end: usize) -> bool {
    if end >= limit {
        return end == limit;
    }
    let op = data[end];
    let known = (0x01..=0x0F).contains(&op) || op >= 0x80;
    known && (frame_at(&data[..limit], end).is_ok() || limit == data.len())
}

/// Whether reading may resume at `pos`: a chunk with consistent framing
/// ([`chunk_frame_at`]) or another record of the data section ([`record_frame_at`]).
fn resync_at(data: &[u8], pos: usize) -> bool {
    chunk_frame_at(data, pos).is_some() || record_frame_at(data, pos)
}

/// The summary section of a complete file: where it starts, and its chunk index offsets,
/// schemas and channels. `None` when the footer or the summary cannot be read.
struct Summary {
    start: usize,
    chunk_offsets: Vec<usize>,
    records: Vec<Record<'static>>,
}

fn read_summary(data: &[u8]) -> Option<Summary> {
    let n = data.len();
    if n < 8 + 9 + 20 + 8 || &data[n - 8..] != mcap::MAGIC {
        return None;
    }
    let fpos = n - 8 - 29;
    if data[fpos] != OP_FOOTER || u64_at(data, fpos + 1)? != 20 {
        return None;
    }
    let start = usize::try_from(u64_at(data, fpos + 9)?).ok()?;
    if start < 8 || start > fpos {
        return None;
    }
    let mut recs = Vec::new();
    let mut offsets = Vec::new();
    let mut p = start;
    while p < fpos {
        let (op, end) = frame_at(data, p).ok()?;
        if end > fpos {
            return None;
        }
        match parse_record(op, &data[p + 9..end]).ok()? {
            Record::ChunkIndex(ci) => offsets.push(usize::try_from(ci.chunk_start_offset).ok()?),
            r @ (Record::Schema { .. } | Record::Channel(_)) => recs.push(r.into_owned()),
            _ => {}
        }
        p = end;
    }
    Some(Summary {
        start,
        chunk_offsets: offsets,
        records: recs,
    })
}

/// What was read so far: schemas and channels by id, metadata and, per chunk offset, the
/// messages of each intact chunk.
#[derive(Default)]
struct Found {
    schemas: HashMap<u16, Schema>,
    channels: HashMap<u16, Channel>,
    metadata: Vec<Metadata>,
    chunks: BTreeMap<usize, Vec<(MessageHeader, Vec<u8>)>>,
    /// Chunk offsets found bad.
    bad: BTreeMap<usize, String>,
}

impl Found {
    /// Keep one record, top-level or from inside the chunk at `chunk`.
    fn take(&mut self, rec: Record<'_>, chunk: usize) {
        match rec {
            Record::Schema { header, data } => {
                self.schemas.entry(header.id).or_insert(Schema {
                    name: header.name,
                    encoding: header.encoding,
                    data: data.into_owned(),
                });
            }
            Record::Channel(c) => {
                self.channels.entry(c.id).or_insert(Channel {
                    schema_id: c.schema_id,
                    topic: c.topic,
                    encoding: c.message_encoding,
                    metadata: c.metadata,
                });
            }
            Record::Message { header, data } => self
                .chunks
                .entry(chunk)
                .or_default()
                .push((header, data.into_owned())),
            Record::Metadata(m) => self.metadata.push(m),
            _ => {}
        }
    }

    /// Read the chunk record whose body is `data[pos + 9..end]`: keep it or mark it bad.
    fn chunk(&mut self, data: &[u8], pos: usize, end: usize) {
        if self.chunks.contains_key(&pos) || self.bad.contains_key(&pos) {
            return;
        }
        match read_chunk(&data[pos + 9..end]) {
            Ok(records) => {
                self.chunks.entry(pos).or_default();
                for r in records {
                    self.take(r, pos);
                }
            }
            Err(why) => {
                self.bad.insert(pos, why);
            }
        }
    }
}

/// Walk the data section from the leading magic to `limit` (the summary's start, or the end
/// of the file), keeping what is intact; after bytes that cannot be framed, resume at the
/// next chunk (see the module doc). Returns the bytes skipped and whether the file ends
/// inside a record.
fn walk(data: &[u8], limit: usize, found: &mut Found, problems: &mut Vec<String>) -> (u64, bool) {
    let mut pos = 8usize;
    let mut skipped = 0u64;
    let mut cut_off = false;
    while pos < limit {
        let framed = frame_at(&data[..limit], pos);
        match framed {
            Ok((OP_DATA_END | OP_FOOTER, _)) => break,
            // A consistent chunk with an unknown compression is read (and reported by
            // name); only resynchronisation insists on a known one.
            Ok((OP_CHUNK, end)) if chunk_framed(&data[..limit], pos).is_some() => {
                found.chunk(data, pos, end);
                pos = end;
                continue;
            }
            Ok((OP_CHUNK, _)) => {}
            Ok((op, end)) if op != 0 => {
                // 0x01–0x0F are the specification's records; 0x80–0xFF are private records
                // a reader skips. Anything else, or a body that does not parse, is corrupt.
                let known = (0x01..=0x0F).contains(&op) || op >= 0x80;
                let parsed = if op >= 0x80 {
                    Some(None)
                } else if known {
                    parse_record(op, &data[pos + 9..end]).ok().map(Some)
                } else {
                    None
                };
                // Taken only when what follows frames too: a corrupt length that still lands
                // inside the file (and a body parser that ignores trailing bytes) must not
                // carry reading into the middle of the next record.
                if let (Some(r), true) = (parsed, follows_ok(data, limit, end)) {
                    if let Some(r) = r {
                        found.take(r, pos);
                    }
                    pos = end;
                    continue;
                }
            }
            _ => {}
        }
        // A record whose length frames but whose body does not parse (a flipped byte in a
        // string length): skip that record alone when a well-framed record follows it.
        if let Ok((op, end)) = framed {
            if op != OP_CHUNK && end > pos + 9 && (end == limit || resync_at(&data[..limit], end)) {
                problems.push(format!(
                    "record at byte {pos} (opcode {op:#04x}, {} bytes) does not parse; skipped",
                    end - pos
                ));
                skipped += (end - pos) as u64;
                pos = end;
                continue;
            }
        }
        // Corrupt framing at `pos` (or the file ends inside this record): resume at the next
        // record whose framing is consistent: a chunk, or a schema, channel, metadata, ...
        // record that parses and is followed by another well-framed record.
        let next = (pos + 1..limit).find(|&p| resync_at(&data[..limit], p));
        let stop = next.unwrap_or(limit);
        if next.is_none() && framed.is_err() && limit == data.len() {
            cut_off = true;
            problems.push(format!(
                "the file ends inside the record at byte {pos} ({} bytes not read)",
                limit - pos
            ));
        } else {
            problems.push(format!(
                "bytes {pos}..{stop} ({} bytes) are not readable records{}",
                stop - pos,
                if data[pos] == OP_CHUNK {
                    " (a chunk whose length or header is corrupt)"
                } else {
                    ""
                }
            ));
            if data[pos] == OP_CHUNK {
                found
                    .bad
                    .entry(pos)
                    .or_insert_with(|| "corrupt length or header".into());
            }
        }
        skipped += (stop - pos) as u64;
        pos = stop;
    }
    (skipped, cut_off)
}

/// Whether the file at `path` starts with the MCAP magic bytes (an MCAP log, complete or not).
pub fn is_mcap_file(path: &Path) -> bool {
    use std::io::Read;
    let mut magic = [0u8; 8];
    File::open(path)
        .and_then(|mut f| f.read_exact(&mut magic))
        .is_ok()
        && magic == mcap::MAGIC
}

/// Rebuild `input` into `output` (which must not exist yet; see the CLI for the checks).
pub fn recover(input: &Path, output: &Path) -> Result<RecoverReport, String> {
    let data =
        std::fs::read(input).map_err(|e| format!("{}: cannot read: {e}", input.display()))?;
    recover_bytes(&data, output).map_err(|e| format!("{}: {e}", input.display()))
}

/// The MCAP log of `len` bytes in `file`, read whole (recovery walks it back and forth) once
/// its first 8 bytes are the MCAP magic: a file that is not an MCAP log costs 8 bytes, not
/// its size.
pub fn read_log(mut file: impl std::io::Read, len: u64) -> Result<Vec<u8>, String> {
    use std::io::Read;
    let mut data = vec![0u8; 8];
    if file.read_exact(&mut data).is_err() || data != mcap::MAGIC {
        return Err(NOT_MCAP.into());
    }
    data.reserve_exact(usize::try_from(len).unwrap_or(0).saturating_sub(8));
    file.take(len - 8)
        .read_to_end(&mut data)
        .map_err(|e| format!("cannot read: {e}"))?;
    Ok(data)
}

/// The error for a file that does not start with the MCAP magic bytes.
const NOT_MCAP: &str = "not an MCAP file (it does not start with the MCAP magic bytes)";

/// [`recover`] on bytes already read.
pub fn recover_bytes(data: &[u8], output: &Path) -> Result<RecoverReport, String> {
    if data.len() < 8 || &data[..8] != mcap::MAGIC {
        return Err(NOT_MCAP.into());
    }
    let summary = read_summary(data);
    let mut rep = RecoverReport {
        was_complete: summary.is_some(),
        chunks_indexed: summary.as_ref().map(|s| s.chunk_offsets.len() as u64),
        ..Default::default()
    };
    let mut found = Found::default();
    let limit = summary.as_ref().map_or(data.len(), |s| s.start);
    let (skipped, cut_off) = walk(data, limit, &mut found, &mut rep.problems);
    rep.skipped_bytes = skipped;
    rep.stopped_early = cut_off;
    if let Some(s) = summary {
        // Chunks the walk could not reach (behind corrupt bytes it skipped) are read where
        // the chunk index says they start; the summary repeats every schema and channel.
        for &off in &s.chunk_offsets {
            match chunk_framed(&data[..limit], off) {
                Some((end, _)) => found.chunk(data, off, end),
                None if !found.chunks.contains_key(&off) => {
                    found.bad.entry(off).or_insert_with(|| {
                        "no chunk with consistent framing where the chunk index points".into()
                    });
                }
                None => {}
            }
        }
        for r in s.records {
            found.take(r, usize::MAX);
        }
    }
    for (off, why) in &found.bad {
        rep.problems
            .push(format!("chunk at byte {off} dropped: {why}"));
    }
    rep.bad_chunks = found.bad.len() as u64;
    rep.chunks = found.chunks.len() as u64;
    let Found {
        schemas,
        channels,
        metadata,
        chunks,
        ..
    } = found;
    let messages = chunks.into_values().flatten();

    // Written under a temporary name in the same directory and linked to `output` only when
    // complete (a link never replaces an existing file): a failure leaves no half file.
    let tmp = output.with_file_name(format!(
        ".{}.recover-{}.tmp",
        output
            .file_name()
            .map_or("out".into(), |n| n.to_string_lossy()),
        std::process::id()
    ));
    let result =
        write_recovered(&tmp, schemas, channels, &metadata, messages, &mut rep).and_then(|()| {
            std::fs::hard_link(&tmp, output)
                .map_err(|e| format!("{}: cannot create: {e}", output.display()))
        });
    let _ = std::fs::remove_file(&tmp);
    result.map(|()| rep)
}

/// Write the kept records to a new MCAP file at `path` (which must not exist).
fn write_recovered(
    path: &Path,
    schemas: HashMap<u16, Schema>,
    channels: HashMap<u16, Channel>,
    metadata: &[Metadata],
    messages: impl Iterator<Item = (MessageHeader, Vec<u8>)>,
    rep: &mut RecoverReport,
) -> Result<(), String> {
    let output = path;
    let file = File::create_new(output)
        .map_err(|e| format!("{}: cannot create: {e}", output.display()))?;
    let mut w = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Lz4))
        .profile("ros2")
        .library(concat!(
            "ehactl ",
            env!("CARGO_PKG_VERSION"),
            " (recovered)"
        ))
        .create(BufWriter::new(file))
        .map_err(|e| format!("{}: {e}", output.display()))?;
    let me = |e: mcap::McapError| format!("{}: {e}", output.display());
    let mut schema_map: HashMap<u16, u16> = HashMap::new();
    let mut channel_map: HashMap<u16, u16> = HashMap::new();
    for m in metadata {
        w.write_metadata(m).map_err(me)?;
    }
    let mut last_ns = 0u64;
    for (h, payload) in messages {
        let new_ch = match channel_map.get(&h.channel_id) {
            Some(&c) => c,
            None => {
                let Some(ch) = channels.get(&h.channel_id) else {
                    // A message whose channel record was lost cannot be decoded: counted.
                    rep.messages_without_channel += 1;
                    continue;
                };
                let sid = if ch.schema_id == 0 {
                    0
                } else {
                    match schema_map.get(&ch.schema_id) {
                        Some(&s) => s,
                        None => {
                            let Some(s) = schemas.get(&ch.schema_id) else {
                                rep.messages_without_channel += 1;
                                continue;
                            };
                            let id = w.add_schema(&s.name, &s.encoding, &s.data).map_err(me)?;
                            schema_map.insert(ch.schema_id, id);
                            id
                        }
                    }
                };
                let id = w
                    .add_channel(sid, &ch.topic, &ch.encoding, &ch.metadata)
                    .map_err(me)?;
                channel_map.insert(h.channel_id, id);
                id
            }
        };
        w.write_to_known_channel(
            &MessageHeader {
                channel_id: new_ch,
                ..h
            },
            &payload,
        )
        .map_err(me)?;
        last_ns = last_ns.max(h.log_time);
        let topic = &channels[&h.channel_id].topic;
        *rep.messages.entry(topic.clone()).or_default() += 1;
    }
    w.finish().map_err(me)?;
    w.into_inner()
        .into_inner()
        .map_err(|e| e.into_error())
        .and_then(|f| f.sync_all())
        .map_err(|e| format!("{}: cannot write: {e}", output.display()))?;
    rep.last_time_s = last_ns as f64 * 1e-9;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mcap_writer::{Compression, Writer};

    /// A log of `chunks` chunks of 100 messages each (hand-written writer, LZ4), complete
    /// or cut after the data section's last chunk; returns its bytes.
    fn log(chunks: u64, complete: bool) -> Vec<u8> {
        let dir = std::env::temp_dir().join(format!("ehactl-recover-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join(format!("log-{chunks}-{complete}.mcap"));
        let mut w = Writer::new(
            File::create(&p).unwrap(),
            "ros2",
            "test",
            Compression::Lz4,
            1 << 20,
        )
        .unwrap();
        let s = w.add_schema("S", "jsonschema", b"{}").unwrap();
        let c = w.add_channel(s, "/x", "json", &BTreeMap::new()).unwrap();
        for k in 0..chunks * 100 {
            w.write_message(c, k as u32, k, k, format!("{{\"k\":{k}}}").as_bytes())
                .unwrap();
            if k % 100 == 99 {
                w.flush().unwrap();
            }
        }
        if complete {
            w.finish().unwrap();
        } else {
            drop(w);
        }
        let b = std::fs::read(&p).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        b
    }

    /// Offsets of the chunk records, found by walking the framing.
    fn chunk_offsets(b: &[u8]) -> Vec<usize> {
        let mut out = Vec::new();
        let mut p = 8;
        while p + 9 <= b.len() {
            let (op, end) = frame_at(b, p).unwrap();
            if op == OP_CHUNK {
                out.push(p);
            }
            if op == OP_DATA_END {
                break;
            }
            p = end;
        }
        out
    }

    fn recover_to_tmp(b: &[u8], name: &str) -> RecoverReport {
        let out =
            std::env::temp_dir().join(format!("ehactl-rec-{name}-{}.mcap", std::process::id()));
        let _ = std::fs::remove_file(&out);
        let rep = recover_bytes(b, &out).unwrap();
        let data = std::fs::read(&out).unwrap();
        let n = mcap::MessageStream::new(&data)
            .unwrap()
            .inspect(|m| assert!(m.is_ok(), "{m:?}"))
            .count() as u64;
        assert_eq!(n, rep.total_messages());
        let _ = std::fs::remove_file(&out);
        rep
    }

    #[test]
    fn a_flipped_byte_drops_one_chunk_and_keeps_the_rest() {
        let good = log(6, true);
        let offs = chunk_offsets(&good);
        assert_eq!(offs.len(), 6);
        let mut bad = good.clone();
        bad[offs[1] + 120] ^= 0x40; // inside chunk 1's compressed records
        let rep = recover_to_tmp(&bad, "flip");
        assert_eq!((rep.chunks, rep.bad_chunks), (5, 1), "{:?}", rep.problems);
        assert_eq!(rep.count("/x"), 500);
        assert_eq!(rep.chunks_indexed, Some(6));
    }

    #[test]
    fn a_flipped_byte_outside_chunks_loses_no_schema_channel_or_message() {
        // A footerless log (killed writer). Byte 25 is the length of the Header's library
        // string (magic 8, opcode 1, length 8, profile "ros2" 4 + 4): flipped, the Header
        // does not parse, but its framing does; the Schema and Channel records after it are
        // intact and must be read, not skipped to the first chunk.
        let good = log(6, false);
        for (at, bit) in [(25usize, 0x01u8), (25, 0x80), (26, 0x10)] {
            let mut bad = good.clone();
            bad[at] ^= bit;
            let rep = recover_to_tmp(&bad, &format!("hdr{at}-{bit}"));
            assert_eq!(rep.messages_without_channel, 0, "{:?}", rep.problems);
            assert_eq!((rep.chunks, rep.bad_chunks), (6, 0), "{:?}", rep.problems);
            assert_eq!(rep.count("/x"), 600);
        }
        // The Header's own record length corrupted (its framing broken): reading resumes at
        // the Schema record, not at the first chunk.
        let mut bad = good.clone();
        bad[9] ^= 0x20;
        let rep = recover_to_tmp(&bad, "hdrlen");
        assert_eq!(rep.messages_without_channel, 0, "{:?}", rep.problems);
        assert_eq!(rep.count("/x"), 600);
    }

    #[test]
    fn a_bad_chunk_length_in_a_cut_off_file_resyncs_on_the_next_chunk() {
        let good = log(6, false);
        let offs = chunk_offsets(&good);
        let mut bad = good.clone();
        let len = u64_at(&bad, offs[2] + 1).unwrap();
        bad[offs[2] + 1..offs[2] + 9].copy_from_slice(&(len + 333).to_le_bytes());
        let rep = recover_to_tmp(&bad, "len");
        assert_eq!((rep.chunks, rep.bad_chunks), (5, 1), "{:?}", rep.problems);
        assert_eq!(rep.count("/x"), 500);
        assert!(rep.skipped_bytes > 0 && rep.chunks_indexed.is_none());
    }
}
