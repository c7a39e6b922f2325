//! A streaming reader of MCAP files for the readers of logs (`ehactl diagnose --data`,
//! `ehactl predict`, the Python bindings' `read_mcap`): the file is read record by record
//! from any [`Read`], so what it costs is one record or chunk at a time plus what the caller
//! keeps, not the whole file. The magic bytes are checked before anything else is read.
//!
//! Every record is checked as [`crate::recover::readable_prefix`] checks a file in memory:
//! its claimed length must fit in what the file has left (MCAP specification
//! <https://mcap.dev/spec>, "Records"), every chunk is decompressed bounded by its declared
//! uncompressed size (at most [`crate::recover::MAX_CHUNK_BYTES`]), its CRC checked and its
//! inner records framed and parsed before the `mcap` crate's record parser sees them. A file
//! that ends at a record boundary without its footer (a cut-off log) is read up to there;
//! `ehactl recover` rebuilds its index.

use crate::recover::{chunk_plain, chunk_records};
use mcap::read::parse_record;
use mcap::records::{Metadata, Record};
use std::collections::HashMap;
use std::io::Read;
use std::sync::Arc;

/// A schema record.
#[derive(Debug, Clone)]
pub struct SchemaInfo {
    /// Schema name (e.g. `ehactl_msgs/msg/Control`).
    pub name: String,
    /// Schema encoding (e.g. `ros2msg`, `jsonschema`).
    pub encoding: String,
    /// Schema text.
    pub data: Vec<u8>,
}

/// A channel record with its schema.
#[derive(Debug, Clone)]
pub struct ChannelInfo {
    /// Topic name.
    pub topic: String,
    /// Message encoding (e.g. `cdr`, `json`).
    pub message_encoding: String,
    /// The channel's schema (`None` for schema id 0).
    pub schema: Option<Arc<SchemaInfo>>,
}

/// One record of interest, in file order.
pub enum Item<'a> {
    /// The header record.
    Header {
        /// Profile (e.g. `ros2`).
        profile: &'a str,
        /// Writing library.
        library: &'a str,
    },
    /// A metadata record.
    Metadata(&'a Metadata),
    /// A message.
    Message {
        /// Its channel.
        channel: &'a ChannelInfo,
        /// Sequence number.
        sequence: u32,
        /// Log time (ns).
        log_time: u64,
        /// Message bytes.
        data: &'a [u8],
    },
}

/// Why a read stopped: the file is not a readable MCAP file (the reason, with its byte
/// offset), or the caller's callback stopped it.
#[derive(Debug)]
pub enum ReadError<E> {
    /// Not a readable MCAP file: why.
    Mcap(String),
    /// The callback's error.
    Stop(E),
}

const OP_HEADER: u8 = 0x01;
const OP_FOOTER: u8 = 0x02;
const OP_SCHEMA: u8 = 0x03;
const OP_CHANNEL: u8 = 0x04;
const OP_MESSAGE: u8 = 0x05;
const OP_CHUNK: u8 = 0x06;
const OP_METADATA: u8 = 0x0C;

/// Schemas and channels seen so far.
#[derive(Default)]
struct Index {
    schemas: HashMap<u16, Arc<SchemaInfo>>,
    channels: HashMap<u16, ChannelInfo>,
}

impl Index {
    /// Take one record (top-level or from a chunk) and hand what the caller wants to `f`.
    fn take<E>(
        &mut self,
        rec: Record<'_>,
        f: &mut impl FnMut(Item<'_>) -> Result<(), E>,
    ) -> Result<(), ReadError<E>> {
        match rec {
            Record::Header(h) => f(Item::Header {
                profile: &h.profile,
                library: &h.library,
            })
            .map_err(ReadError::Stop)?,
            Record::Schema { header, data } => {
                self.schemas.entry(header.id).or_insert_with(|| {
                    Arc::new(SchemaInfo {
                        name: header.name,
                        encoding: header.encoding,
                        data: data.into_owned(),
                    })
                });
            }
            Record::Channel(c) if !self.channels.contains_key(&c.id) => {
                let schema = match c.schema_id {
                    0 => None,
                    id => Some(self.schemas.get(&id).cloned().ok_or_else(|| {
                        ReadError::Mcap(format!(
                            "channel {} ({}) names schema {id}, which no earlier record defines",
                            c.id, c.topic
                        ))
                    })?),
                };
                let info = ChannelInfo {
                    topic: c.topic,
                    message_encoding: c.message_encoding,
                    schema,
                };
                self.channels.insert(c.id, info);
            }
            Record::Message { header, data } => {
                let channel = self.channels.get(&header.channel_id).ok_or_else(|| {
                    ReadError::Mcap(format!(
                        "message (sequence {}) on channel {}, which no earlier record defines",
                        header.sequence, header.channel_id
                    ))
                })?;
                f(Item::Message {
                    channel,
                    sequence: header.sequence,
                    log_time: header.log_time,
                    data: &data,
                })
                .map_err(ReadError::Stop)?;
            }
            Record::Metadata(m) => f(Item::Metadata(&m)).map_err(ReadError::Stop)?,
            _ => {}
        }
        Ok(())
    }
}

impl Index {
    /// Take the top-level record of opcode `op` whose body is `body`, at byte `pos`: a chunk's
    /// records one by one once the chunk checks out, any other record parsed.
    fn record<E>(
        &mut self,
        op: u8,
        body: &[u8],
        pos: u64,
        f: &mut impl FnMut(Item<'_>) -> Result<(), E>,
    ) -> Result<(), ReadError<E>> {
        if op != OP_CHUNK {
            let rec = parse_record(op, body).map_err(|e| {
                ReadError::Mcap(format!("record at byte {pos} (opcode {op:#04x}): {e}"))
            })?;
            return self.take(rec, f);
        }
        let plain = chunk_plain(body)
            .map_err(|why| ReadError::Mcap(format!("corrupt chunk at byte {pos}: {why}")))?;
        let mut stop = None;
        chunk_records(&plain, |rec| match self.take(rec, f) {
            Ok(()) => Ok(()),
            Err(ReadError::Mcap(why)) => Err(why),
            Err(e) => {
                stop = Some(e);
                Err(String::new())
            }
        })
        .map_err(|why| {
            stop.take()
                .unwrap_or_else(|| ReadError::Mcap(format!("corrupt chunk at byte {pos}: {why}")))
        })
    }
}

/// Fill `buf` from `r`; the number of bytes read (less than `buf.len()` only at the end).
fn read_full(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

/// Read the MCAP file of `len` bytes from `r` (at most `len` bytes are read), handing its
/// header, metadata and messages to `f` in file order.
pub fn for_each<E>(
    r: impl Read,
    len: u64,
    mut f: impl FnMut(Item<'_>) -> Result<(), E>,
) -> Result<(), ReadError<E>> {
    let mut r = r.take(len);
    let io = |e: std::io::Error| ReadError::Mcap(format!("read error: {e}"));
    let mut magic = [0u8; 8];
    if read_full(&mut r, &mut magic).map_err(io)? < 8 || magic != *mcap::MAGIC {
        return Err(ReadError::Mcap(
            "does not start with the MCAP magic bytes".into(),
        ));
    }
    let mut index = Index::default();
    let mut pos = 8u64;
    let mut body = Vec::new();
    loop {
        let mut head = [0u8; 9];
        match read_full(&mut r, &mut head).map_err(io)? {
            0 => return Ok(()), // ends at a record boundary, without a footer
            9 => {}
            _ => {
                return Err(ReadError::Mcap(format!(
                    "cut off at byte {pos} (a record header)"
                )))
            }
        }
        let op = head[0];
        let rlen = u64::from_le_bytes(head[1..].try_into().expect("8 bytes"));
        let left = len - pos - 9;
        if rlen > left {
            return Err(ReadError::Mcap(format!(
                "record at byte {pos} claims {rlen} bytes; only {left} remain (cut off or corrupt)"
            )));
        }
        if !matches!(
            op,
            OP_HEADER | OP_SCHEMA | OP_CHANNEL | OP_MESSAGE | OP_CHUNK | OP_METADATA
        ) {
            // Footer: done. Anything else (indexes, attachments, summary records): skipped
            // without being held.
            if op == OP_FOOTER {
                return Ok(());
            }
            std::io::copy(&mut (&mut r).take(rlen), &mut std::io::sink()).map_err(io)?;
            pos += 9 + rlen;
            continue;
        }
        body.clear();
        body.resize(rlen as usize, 0);
        read_full(&mut r, &mut body).map_err(io)?;
        index.record(op, &body, pos, &mut f)?;
        // A chunk much larger than the next ones is not kept reserved.
        if body.capacity() > 4 << 20 {
            body = Vec::new();
        }
        pos += 9 + rlen;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    /// An MCAP file written by the `mcap` crate's writer (the official Rust writer of the
    /// format's authors), zstd chunks: 200 small JSON messages, one message of a 10 MB string
    /// of one repeated character (it compresses more than 4096:1), and one metadata record.
    fn official_file() -> Vec<u8> {
        let mut out = std::io::Cursor::new(Vec::new());
        let mut w = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .profile("")
            .create(&mut out)
            .unwrap();
        let s = w.add_schema("S", "jsonschema", b"{}").unwrap();
        let c = w.add_channel(s, "/x", "json", &BTreeMap::new()).unwrap();
        let big = w.add_channel(0, "/big", "text", &BTreeMap::new()).unwrap();
        let header = |channel_id, k: u32| mcap::records::MessageHeader {
            channel_id,
            sequence: k,
            log_time: u64::from(k) * 1000,
            publish_time: u64::from(k) * 1000,
        };
        for k in 0..200u32 {
            w.write_to_known_channel(&header(c, k), format!("{{\"k\":{k}}}").as_bytes())
                .unwrap();
        }
        w.write_to_known_channel(&header(big, 200), &vec![b'a'; 10_000_000])
            .unwrap();
        let md = mcap::records::Metadata {
            name: "m".into(),
            metadata: BTreeMap::from([("key".to_string(), "value".to_string())]),
        };
        w.write_metadata(&md).unwrap();
        w.finish().unwrap();
        drop(w);
        out.into_inner()
    }

    /// A message: topic, sequence, log time, bytes.
    type Msg = (String, u32, u64, Vec<u8>);

    /// Every message, by `for_each`.
    fn ours(b: &[u8]) -> Result<Vec<Msg>, ReadError<()>> {
        let mut got = Vec::new();
        for_each(b, b.len() as u64, |item| {
            if let Item::Message {
                channel,
                sequence,
                log_time,
                data,
            } = item
            {
                got.push((channel.topic.clone(), sequence, log_time, data.to_vec()));
            }
            Ok(())
        })?;
        Ok(got)
    }

    #[test]
    fn reads_a_highly_compressed_file_as_the_official_reader_does() {
        let b = official_file();
        // The big message's chunk: ~10 MB from a few kB of zstd.
        assert!(b.len() < 100_000, "{} bytes", b.len());
        let official: Vec<_> = mcap::MessageStream::new(&b)
            .unwrap()
            .map(|m| {
                let m = m.unwrap();
                (
                    m.channel.topic.clone(),
                    m.sequence,
                    m.log_time,
                    m.data.to_vec(),
                )
            })
            .collect();
        assert_eq!(official.len(), 201);
        let got = ours(&b).unwrap();
        assert!(
            got == official,
            "messages differ from the official reader's"
        );
        // The in-memory check agrees (it refused the file under a fixed ratio cap).
        assert_eq!(crate::recover::readable_prefix(&b).1, None);
        let mut meta = Vec::new();
        for_each::<()>(&b[..], b.len() as u64, |item| {
            if let Item::Metadata(m) = item {
                meta.push((m.name.clone(), m.metadata["key"].clone()));
            }
            Ok(())
        })
        .unwrap();
        assert_eq!(meta, [("m".to_string(), "value".to_string())]);
    }

    /// Hands out `head`, then fails the test if read again.
    struct ThenPanic<'a>(&'a [u8]);

    impl Read for ThenPanic<'_> {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            assert!(!self.0.is_empty(), "read past the bytes that decide");
            let n = self.0.read(buf)?;
            Ok(n)
        }
    }

    #[test]
    fn a_file_that_is_not_mcap_is_refused_on_its_first_8_bytes() {
        // A 1 GB file of NULs, as far as the reader is told: only 8 bytes are read.
        let e = for_each::<()>(ThenPanic(&[0u8; 8]), 1 << 30, |_| Ok(()));
        assert!(
            matches!(&e, Err(ReadError::Mcap(w)) if w.contains("magic")),
            "{e:?}"
        );
    }

    #[test]
    fn lengths_and_declared_sizes_are_checked_before_allocating() {
        // A record claiming more bytes than the file has left: refused on its header.
        let mut b = mcap::MAGIC.to_vec();
        b.push(OP_METADATA);
        b.extend_from_slice(&u64::MAX.to_le_bytes());
        let e = for_each::<()>(ThenPanic(&b), 1 << 30, |_| Ok(()));
        assert!(
            matches!(&e, Err(ReadError::Mcap(w)) if w.contains("claims 18446744073709551615 bytes")),
            "{e:?}"
        );
        // A zstd chunk declaring more than MAX_CHUNK_BYTES uncompressed: refused on its
        // header, before decompression (chunk body: start, end, uncompressed size, CRC,
        // compression, stored size, records; MCAP spec "Chunk").
        let stored = [0u8; 16];
        let mut body = Vec::new();
        body.extend_from_slice(&0u64.to_le_bytes());
        body.extend_from_slice(&0u64.to_le_bytes());
        body.extend_from_slice(&(crate::recover::MAX_CHUNK_BYTES + 1).to_le_bytes());
        body.extend_from_slice(&0u32.to_le_bytes());
        body.extend_from_slice(&4u32.to_le_bytes());
        body.extend_from_slice(b"zstd");
        body.extend_from_slice(&(stored.len() as u64).to_le_bytes());
        body.extend_from_slice(&stored);
        let mut b = mcap::MAGIC.to_vec();
        b.push(OP_CHUNK);
        b.extend_from_slice(&(body.len() as u64).to_le_bytes());
        b.extend_from_slice(&body);
        let e = ours(&b).unwrap_err();
        assert!(
            matches!(&e, ReadError::Mcap(w) if w.contains("corrupt chunk at byte 8: claims 1000000001 bytes")),
            "{e:?}"
        );
    }
}
