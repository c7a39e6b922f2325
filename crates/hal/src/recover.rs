//! `ehactl recover`: rebuild a valid, indexed MCAP file from a log whose writer was killed
//! (SIGKILL, power loss, full disk) before it wrote the summary section and footer.
//!
//! The damaged file is read record by record from the start; every schema, channel,
//! metadata record and every message of every *complete* chunk whose CRC checks out is
//! copied, in order, into a new file written by the `mcap` crate (chunk CRCs, message and
//! chunk indexes, statistics, summary, footer). Reading stops at the first record that is
//! cut off or corrupt: a chunk is taken whole or not at all. The official readers do not
//! do this themselves (they refuse a file without a footer or with a truncated record),
//! hence this module.

use mcap::read::{ChunkReader, LinearReader, Options};
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
    /// Complete chunks copied.
    pub chunks: u64,
    /// Chunks dropped because their CRC or contents were bad.
    pub bad_chunks: u64,
    /// Reading stopped at a cut-off or corrupt record before the end of the file.
    pub stopped_early: bool,
    /// The input already had a valid footer (nothing was lost).
    pub was_complete: bool,
    /// Log time of the last recovered message (s).
    pub last_time_s: f64,
}

impl RecoverReport {
    /// Messages copied on `topic`.
    pub fn count(&self, topic: &str) -> u64 {
        self.messages.get(topic).copied().unwrap_or(0)
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

/// Largest decompression ratio accepted for an LZ4 / Zstd chunk (LZ4's format limit is
/// ≈ 255:1). A chunk header claiming more is corrupt.
const MAX_CHUNK_RATIO: u64 = 256;

/// Whether a chunk's claimed uncompressed size is possible for its stored size. The `mcap`
/// crate (0.24) allocates the claimed size before decompressing, so a corrupt header would
/// abort the process with an allocation failure (found by tests/rust/fuzz_parsers.rs):
/// every chunk is checked here first.
pub fn chunk_size_plausible(compression: &str, uncompressed: u64, stored: u64) -> bool {
    match compression {
        "" => uncompressed == stored,
        _ => uncompressed <= stored.saturating_mul(MAX_CHUNK_RATIO).saturating_add(4096),
    }
}

/// Walk the top-level records of an MCAP file (opcode, length, body) without decompressing
/// anything. Returns the length of the well-formed prefix (magic plus whole records whose
/// lengths fit in the file and whose chunk headers pass [`chunk_size_plausible`]) and, if
/// the walk stopped early, why. The `mcap` crate (0.24) reserves a record's claimed length
/// before checking it against the data, so a corrupt length field would abort the process
/// with an allocation failure (found by tests/rust/fuzz_parsers.rs): only this prefix may be
/// handed to it.
pub fn readable_prefix(data: &[u8]) -> (usize, Option<String>) {
    let u64_at = |b: &[u8], at: usize| -> Option<u64> {
        b.get(at..at + 8)
            .map(|s| u64::from_le_bytes(s.try_into().unwrap()))
    };
    let u32_at = |b: &[u8], at: usize| -> Option<u32> {
        b.get(at..at + 4)
            .map(|s| u32::from_le_bytes(s.try_into().unwrap()))
    };
    if data.len() < 8 || &data[..8] != mcap::MAGIC {
        return (0, Some("does not start with the MCAP magic bytes".into()));
    }
    let mut pos = 8usize; // after the magic
    loop {
        if pos == data.len() {
            return (pos, None);
        }
        if pos + 9 > data.len() {
            return (
                pos,
                Some(format!("cut off at byte {pos} (a record header)")),
            );
        }
        let op = data[pos];
        let len = u64_at(data, pos + 1).unwrap_or(u64::MAX);
        let body_start = pos + 9;
        let Some(body_end) = usize::try_from(len)
            .ok()
            .and_then(|l| body_start.checked_add(l))
            .filter(|&e| e <= data.len())
        else {
            return (
                pos,
                Some(format!(
                    "record at byte {pos} claims {len} bytes; only {} remain (cut off or corrupt)",
                    data.len() - body_start
                )),
            );
        };
        if op == 0x06 {
            let b = &data[body_start..body_end];
            let parsed = (|| {
                let uncompressed = u64_at(b, 16)?;
                let clen = u32_at(b, 28)? as usize;
                let compression =
                    std::str::from_utf8(b.get(32..32usize.checked_add(clen)?)?).ok()?;
                let stored = u64_at(b, 32 + clen)?;
                (stored <= (b.len() - 40 - clen) as u64).then_some(())?;
                Some((uncompressed, compression.to_string(), stored))
            })();
            match parsed {
                Some((u, c, st)) if chunk_size_plausible(&c, u, st) => {
                    if let Err(why) = chunk_contents_valid(b, u, &c, st) {
                        return (pos, Some(format!("corrupt chunk at byte {pos}: {why}")));
                    }
                }
                Some((u, c, st)) => {
                    return (
                        pos,
                        Some(format!(
                            "corrupt chunk at byte {pos}: claims {u} bytes uncompressed from {st} bytes of `{c}`"
                        )),
                    )
                }
                None => return (pos, Some(format!("corrupt chunk header at byte {pos}"))),
            }
        }
        pos = body_end;
        if op == 0x02 {
            // Footer: the magic follows.
            return (data.len().min(pos + 8), None);
        }
    }
}

/// Decompress a chunk body (bounded by its plausible claimed size), check its CRC when it
/// has one, and walk its records: every record length must fit. Only then may the `mcap`
/// crate parse it (see [`readable_prefix`]).
fn chunk_contents_valid(
    body: &[u8],
    uncompressed: u64,
    compression: &str,
    stored: u64,
) -> Result<(), String> {
    use std::io::Read;
    let crc = u32::from_le_bytes(body[24..28].try_into().unwrap());
    let start = body.len() - stored as usize;
    let raw = &body[start..];
    let owned;
    let plain: &[u8] = match compression {
        "" => raw,
        "lz4" => {
            let mut out = Vec::with_capacity(uncompressed as usize);
            let dec = lz4::Decoder::new(raw).map_err(|e| format!("lz4: {e}"))?;
            dec.take(uncompressed + 1)
                .read_to_end(&mut out)
                .map_err(|e| format!("lz4: {e}"))?;
            owned = out;
            &owned
        }
        other => return Err(format!("unsupported chunk compression `{other}`")),
    };
    if plain.len() as u64 != uncompressed {
        return Err(format!(
            "decompresses to {} bytes, header says {uncompressed}",
            plain.len()
        ));
    }
    if crc != 0 && crc32fast::hash(plain) != crc {
        return Err("CRC mismatch".into());
    }
    let mut p = 0usize;
    while p < plain.len() {
        let len = plain
            .get(p + 1..p + 9)
            .map(|s| u64::from_le_bytes(s.try_into().unwrap()))
            .ok_or("record header cut off")?;
        let end = usize::try_from(len)
            .ok()
            .and_then(|l| (p + 9).checked_add(l))
            .filter(|&e| e <= plain.len())
            .ok_or("record length beyond the chunk")?;
        p = end;
    }
    Ok(())
}

/// What was read so far: schemas and channels by id, metadata and messages in file order.
#[derive(Default)]
struct Found {
    schemas: HashMap<u16, Schema>,
    channels: HashMap<u16, Channel>,
    metadata: Vec<Metadata>,
    messages: Vec<(MessageHeader, Vec<u8>)>,
}

impl Found {
    /// Keep one record, top-level or from inside a chunk.
    fn take(&mut self, rec: Record<'_>) {
        match rec {
            Record::Schema { header, data } => {
                self.schemas.insert(
                    header.id,
                    Schema {
                        name: header.name,
                        encoding: header.encoding,
                        data: data.into_owned(),
                    },
                );
            }
            Record::Channel(c) => {
                self.channels.insert(
                    c.id,
                    Channel {
                        schema_id: c.schema_id,
                        topic: c.topic,
                        encoding: c.message_encoding,
                        metadata: c.metadata,
                    },
                );
            }
            Record::Message { header, data } => self.messages.push((header, data.into_owned())),
            Record::Metadata(m) => self.metadata.push(m),
            _ => {}
        }
    }
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
    let (end, problem) = readable_prefix(&data);
    if end == 0 {
        return Err(format!(
            "{}: not an MCAP file (it does not start with the MCAP magic bytes)",
            input.display()
        ));
    }
    let mut rep = RecoverReport {
        was_complete: data.len() >= 16 && &data[data.len() - 8..] == mcap::MAGIC,
        stopped_early: problem.is_some(),
        ..Default::default()
    };
    let mut found = Found::default();
    let reader = LinearReader::new_with_options(&data[..end], Options::IgnoreEndMagic.into())
        .map_err(|e| format!("{}: {e}", input.display()))?;
    for rec in reader {
        let rec = match rec {
            Ok(r) => r,
            Err(_) => {
                rep.stopped_early = true;
                break;
            }
        };
        match rec {
            Record::Chunk { header, data } => {
                // Sizes, contents and CRC were checked by `readable_prefix`; the chunk is still
                // taken whole or not at all.
                let inner: Option<Vec<Record<'_>>> = ChunkReader::new(header, &data)
                    .ok()
                    .and_then(|cr| cr.collect::<Result<Vec<_>, _>>().ok());
                match inner {
                    Some(records) => {
                        rep.chunks += 1;
                        records.into_iter().for_each(|r| found.take(r));
                    }
                    None => rep.bad_chunks += 1,
                }
            }
            // The summary section of a complete file repeats what we already have.
            Record::DataEnd(_) | Record::Footer(_) => break,
            other => found.take(other),
        }
    }
    let Found {
        schemas,
        channels,
        metadata,
        messages,
    } = found;

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
    for m in &metadata {
        w.write_metadata(m).map_err(me)?;
    }
    let mut last_ns = 0u64;
    for (h, payload) in &messages {
        let new_ch = match channel_map.get(&h.channel_id) {
            Some(&c) => c,
            None => {
                let Some(ch) = channels.get(&h.channel_id) else {
                    continue; // a message whose channel record was lost cannot be decoded
                };
                let sid = if ch.schema_id == 0 {
                    0
                } else {
                    match schema_map.get(&ch.schema_id) {
                        Some(&s) => s,
                        None => {
                            let Some(s) = schemas.get(&ch.schema_id) else {
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
                ..*h
            },
            payload,
        )
        .map_err(me)?;
        last_ns = last_ns.max(h.log_time);
        let topic = &channels[&h.channel_id].topic;
        *rep.messages.entry(topic.clone()).or_default() += 1;
    }
    w.finish().map_err(me)?;
    rep.last_time_s = last_ns as f64 * 1e-9;
    Ok(rep)
}
