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

/// Rebuild `input` into `output` (which must not exist yet; see the CLI for the checks).
pub fn recover(input: &Path, output: &Path) -> Result<RecoverReport, String> {
    let data = std::fs::read(input).map_err(|e| format!("{}: cannot read: {e}", input.display()))?;
    if data.len() < 8 || &data[..8] != mcap::MAGIC {
        return Err(format!(
            "{}: not an MCAP file (it does not start with the MCAP magic bytes)",
            input.display()
        ));
    }
    let mut rep = RecoverReport {
        was_complete: data.len() >= 16 && &data[data.len() - 8..] == mcap::MAGIC,
        ..Default::default()
    };
    let mut schemas: HashMap<u16, Schema> = HashMap::new();
    let mut channels: HashMap<u16, Channel> = HashMap::new();
    let mut metadata: Vec<Metadata> = Vec::new();
    // Messages in file order: (channel id, header, payload).
    let mut messages: Vec<(MessageHeader, Vec<u8>)> = Vec::new();
    let reader = LinearReader::new_with_options(&data, Options::IgnoreEndMagic.into())
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
            Record::Schema { header, data } => {
                schemas.insert(
                    header.id,
                    Schema {
                        name: header.name,
                        encoding: header.encoding,
                        data: data.into_owned(),
                    },
                );
            }
            Record::Channel(c) => {
                channels.insert(
                    c.id,
                    Channel {
                        schema_id: c.schema_id,
                        topic: c.topic,
                        encoding: c.message_encoding,
                        metadata: c.metadata,
                    },
                );
            }
            Record::Message { header, data } => messages.push((header, data.into_owned())),
            Record::Metadata(m) => metadata.push(m),
            Record::Chunk { header, data } => {
                // Take the chunk whole only if every record in it parses and its CRC holds.
                let mut inner = Vec::new();
                let mut ok = true;
                match ChunkReader::new(header, &data) {
                    Ok(cr) => {
                        for r in cr {
                            match r {
                                Ok(r) => inner.push(r),
                                Err(_) => {
                                    ok = false;
                                    break;
                                }
                            }
                        }
                    }
                    Err(_) => ok = false,
                }
                if !ok {
                    rep.bad_chunks += 1;
                    continue;
                }
                rep.chunks += 1;
                for r in inner {
                    match r {
                        Record::Schema { header, data } => {
                            schemas.insert(
                                header.id,
                                Schema {
                                    name: header.name,
                                    encoding: header.encoding,
                                    data: data.into_owned(),
                                },
                            );
                        }
                        Record::Channel(c) => {
                            channels.insert(
                                c.id,
                                Channel {
                                    schema_id: c.schema_id,
                                    topic: c.topic,
                                    encoding: c.message_encoding,
                                    metadata: c.metadata,
                                },
                            );
                        }
                        Record::Message { header, data } => {
                            messages.push((header, data.into_owned()))
                        }
                        _ => {}
                    }
                }
            }
            // The summary section of a complete file repeats what we already have.
            Record::DataEnd(_) | Record::Footer(_) => break,
            _ => {}
        }
    }

    let file = File::create_new(output)
        .map_err(|e| format!("{}: cannot create: {e}", output.display()))?;
    let mut w = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Lz4))
        .profile("ros2")
        .library(concat!("ehactl ", env!("CARGO_PKG_VERSION"), " (recovered)"))
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

