//! Read any ehactl MCAP log into columns with the `mcap` crate (chunk CRCs checked).
//! CDR channels are decoded from their own `ros2msg` schema text (primitive fields only,
//! CDR alignment relative to the 4-byte encapsulation header), so a log whose messages gain
//! fields still reads; JSON channels are returned as text for Python to parse.

use numpy::IntoPyArray;
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::collections::BTreeMap;
use std::path::PathBuf;

#[derive(Clone, Copy, PartialEq)]
enum Prim {
    F64,
    F32,
    I64,
    I32,
    I16,
    I8,
    U64,
    U32,
    U16,
    U8,
    Bool,
}

impl Prim {
    fn parse(s: &str) -> Option<Prim> {
        Some(match s {
            "float64" => Prim::F64,
            "float32" => Prim::F32,
            "int64" => Prim::I64,
            "int32" => Prim::I32,
            "int16" => Prim::I16,
            "int8" => Prim::I8,
            "uint64" => Prim::U64,
            "uint32" => Prim::U32,
            "uint16" => Prim::U16,
            "uint8" | "byte" | "char" => Prim::U8,
            "bool" => Prim::Bool,
            _ => return None,
        })
    }
    fn size(self) -> usize {
        match self {
            Prim::F64 | Prim::I64 | Prim::U64 => 8,
            Prim::F32 | Prim::I32 | Prim::U32 => 4,
            Prim::I16 | Prim::U16 => 2,
            Prim::I8 | Prim::U8 | Prim::Bool => 1,
        }
    }
}

/// One field of a flat message: (name, type, byte offset after the CDR header).
type Field = (String, Prim, usize);

/// Field layout of a flat ros2msg schema and the message size (bytes after the header).
fn layout(topic: &str, schema: &str) -> Result<(Vec<Field>, usize), String> {
    let mut out = Vec::new();
    let mut off = 0usize;
    for raw in schema.lines() {
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        if line.starts_with("====") {
            break; // dependent message definitions follow; ehactl messages are flat
        }
        let mut it = line.split_whitespace();
        let (Some(ty), Some(name)) = (it.next(), it.next()) else {
            return Err(format!("{topic}: cannot parse schema line `{raw}`"));
        };
        if name.contains('=') || it.next().is_some_and(|t| t.starts_with('=')) {
            continue; // constant
        }
        let Some(p) = Prim::parse(ty) else {
            return Err(format!(
                "{topic}: schema field `{name}` has type `{ty}`; only flat primitive messages are supported"
            ));
        };
        let a = p.size();
        off = off.div_ceil(a) * a;
        out.push((name.to_string(), p, off));
        off += a;
    }
    Ok((out, off))
}

enum Col {
    F(Vec<f64>),
    I(Vec<i64>),
    U(Vec<u64>),
    B(Vec<bool>),
}

struct CdrTopic {
    fields: Vec<Field>,
    size: usize,
    cols: Vec<Col>,
    log_time: Vec<u64>,
    sequence: Vec<u32>,
}

fn rd<const N: usize>(b: &[u8], off: usize) -> [u8; N] {
    let mut a = [0u8; N];
    a.copy_from_slice(&b[off..off + N]);
    a
}

impl CdrTopic {
    fn push(&mut self, topic: &str, data: &[u8]) -> Result<(), String> {
        if data.len() < 4 + self.size {
            return Err(format!(
                "{topic}: message of {} bytes, schema needs {}",
                data.len(),
                4 + self.size
            ));
        }
        let le = match data[1] {
            0x01 => true,
            0x00 => false,
            k => {
                return Err(format!(
                    "{topic}: CDR encapsulation kind {k:#x} is not plain CDR"
                ))
            }
        };
        let b = &data[4..];
        for ((_, p, off), col) in self.fields.iter().zip(self.cols.iter_mut()) {
            let off = *off;
            macro_rules! num {
                ($t:ty, $n:literal) => {{
                    let a = rd::<$n>(b, off);
                    if le {
                        <$t>::from_le_bytes(a)
                    } else {
                        <$t>::from_be_bytes(a)
                    }
                }};
            }
            match (p, col) {
                (Prim::F64, Col::F(v)) => v.push(num!(f64, 8)),
                (Prim::F32, Col::F(v)) => v.push(num!(f32, 4) as f64),
                (Prim::I64, Col::I(v)) => v.push(num!(i64, 8)),
                (Prim::I32, Col::I(v)) => v.push(num!(i32, 4) as i64),
                (Prim::I16, Col::I(v)) => v.push(num!(i16, 2) as i64),
                (Prim::I8, Col::I(v)) => v.push(b[off] as i8 as i64),
                (Prim::U64, Col::U(v)) => v.push(num!(u64, 8)),
                (Prim::U32, Col::U(v)) => v.push(num!(u32, 4) as u64),
                (Prim::U16, Col::U(v)) => v.push(num!(u16, 2) as u64),
                (Prim::U8, Col::U(v)) => v.push(b[off] as u64),
                (Prim::Bool, Col::B(v)) => v.push(b[off] != 0),
                _ => unreachable!("column kind follows the primitive"),
            }
        }
        Ok(())
    }
}

/// Read an MCAP file: returns dict with `cdr` {topic: {field: array, _log_time, _sequence}},
/// `json` {topic: [text, ...]}, `other` {topic: count}, `schemas` {topic: (name, encoding)},
/// `metadata` {name: {key: value}}, `profile`, `library`.
#[pyfunction]
pub fn read_mcap_raw<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    let bytes = std::fs::read(&path).map_err(|e| {
        if e.kind() == std::io::ErrorKind::NotFound {
            pyo3::exceptions::PyFileNotFoundError::new_err((
                2,
                format!("MCAP file not found: {}", path.display()),
                path.display().to_string(),
            ))
        } else {
            PyOSError::new_err(format!("cannot read {}: {e}", path.display()))
        }
    })?;
    let bad = |what: String| PyValueError::new_err(format!("{}: {what}", path.display()));
    let mut cdr: BTreeMap<String, CdrTopic> = BTreeMap::new();
    let mut json: BTreeMap<String, Vec<String>> = BTreeMap::new();
    let mut other: BTreeMap<String, u64> = BTreeMap::new();
    let mut schemas: BTreeMap<String, (String, String)> = BTreeMap::new();
    let mut metadata: BTreeMap<String, BTreeMap<String, String>> = BTreeMap::new();
    let mut profile = String::new();
    let mut library = String::new();
    let stream = mcap::MessageStream::new(&bytes)
        .map_err(|e| bad(format!("not a readable MCAP file ({e})")))?;
    py.detach(|| -> Result<(), String> {
        for m in stream {
            let m = m.map_err(|e| format!("MCAP read error: {e}"))?;
            let topic = &m.channel.topic;
            let enc = m.channel.message_encoding.as_str();
            if !schemas.contains_key(topic) {
                let (sn, se) = m
                    .channel
                    .schema
                    .as_ref()
                    .map(|s| (s.name.clone(), s.encoding.clone()))
                    .unwrap_or_default();
                schemas.insert(topic.clone(), (sn, se));
            }
            match enc {
                "cdr" => {
                    if !cdr.contains_key(topic) {
                        let schema = m
                            .channel
                            .schema
                            .as_ref()
                            .ok_or_else(|| format!("{topic}: CDR channel without a schema"))?;
                        if schema.encoding != "ros2msg" {
                            return Err(format!(
                                "{topic}: schema encoding `{}`, expected ros2msg",
                                schema.encoding
                            ));
                        }
                        let text = String::from_utf8_lossy(&schema.data);
                        let (fields, size) = layout(topic, &text)?;
                        let cols = fields
                            .iter()
                            .map(|(_, p, _)| match p {
                                Prim::F64 | Prim::F32 => Col::F(Vec::new()),
                                Prim::I64 | Prim::I32 | Prim::I16 | Prim::I8 => Col::I(Vec::new()),
                                Prim::Bool => Col::B(Vec::new()),
                                _ => Col::U(Vec::new()),
                            })
                            .collect();
                        cdr.insert(
                            topic.clone(),
                            CdrTopic {
                                fields,
                                size,
                                cols,
                                log_time: Vec::new(),
                                sequence: Vec::new(),
                            },
                        );
                    }
                    let t = cdr.get_mut(topic).expect("inserted above");
                    t.push(topic, &m.data)?;
                    t.log_time.push(m.log_time);
                    t.sequence.push(m.sequence);
                }
                "json" => json
                    .entry(topic.clone())
                    .or_default()
                    .push(String::from_utf8_lossy(&m.data).into_owned()),
                _ => *other.entry(topic.clone()).or_default() += 1,
            }
        }
        for rec in mcap::read::LinearReader::new(&bytes).map_err(|e| e.to_string())? {
            match rec.map_err(|e| format!("MCAP read error: {e}"))? {
                mcap::records::Record::Header(h) => {
                    profile = h.profile;
                    library = h.library;
                }
                mcap::records::Record::Metadata(md) => {
                    metadata.insert(md.name, md.metadata);
                }
                _ => {}
            }
        }
        Ok(())
    })
    .map_err(bad)?;

    let out = PyDict::new(py);
    let cdr_d = PyDict::new(py);
    for (topic, t) in cdr {
        let d = PyDict::new(py);
        for ((name, _, _), col) in t.fields.into_iter().zip(t.cols) {
            match col {
                Col::F(v) => d.set_item(name, v.into_pyarray(py))?,
                Col::I(v) => d.set_item(name, v.into_pyarray(py))?,
                Col::U(v) => d.set_item(name, v.into_pyarray(py))?,
                Col::B(v) => d.set_item(name, v.into_pyarray(py))?,
            }
        }
        d.set_item("_log_time", t.log_time.into_pyarray(py))?;
        d.set_item("_sequence", t.sequence.into_pyarray(py))?;
        cdr_d.set_item(topic, d)?;
    }
    out.set_item("cdr", cdr_d)?;
    let json_d = PyDict::new(py);
    for (topic, msgs) in json {
        json_d.set_item(topic, PyList::new(py, msgs)?)?;
    }
    out.set_item("json", json_d)?;
    out.set_item("other", other)?;
    out.set_item("schemas", schemas)?;
    out.set_item("metadata", metadata)?;
    out.set_item("profile", profile)?;
    out.set_item("library", library)?;
    Ok(out)
}
