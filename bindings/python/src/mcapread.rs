//! Read any ehactl MCAP log into columns with the `mcap` crate, after the checks of the
//! CLI's reader (a bounded regular file, every chunk's sizes, decompression and CRC).
//! CDR channels are decoded from their own `ros2msg` schema text by the log format's one
//! decoder, `ehactl_log::record::FlatSchema` (primitive fields only, CDR alignment relative
//! to the 4-byte encapsulation header), so a log whose messages gain fields still reads;
//! JSON channels are returned as text for Python to parse.

use ehactl_log::record::{FlatSchema, Prim, Value};
use numpy::IntoPyArray;
use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::collections::BTreeMap;
use std::path::PathBuf;

enum Col {
    F(Vec<f64>),
    I(Vec<i64>),
    U(Vec<u64>),
    B(Vec<bool>),
}

struct CdrTopic {
    schema: FlatSchema,
    cols: Vec<Col>,
    log_time: Vec<u64>,
    sequence: Vec<u32>,
}

impl CdrTopic {
    fn push(&mut self, data: &[u8]) -> Result<(), String> {
        let cols = &mut self.cols;
        self.schema
            .decode(data, |i, v| match (&mut cols[i], v) {
                (Col::F(c), Value::F(x)) => c.push(x),
                (Col::I(c), Value::I(x)) => c.push(x),
                (Col::U(c), Value::U(x)) => c.push(x),
                (Col::B(c), Value::B(x)) => c.push(x),
                _ => unreachable!("column kind follows the primitive"),
            })
            .map_err(|e| e.to_string())
    }
}

/// Read an MCAP file: returns dict with `cdr` {topic: {field: array, _log_time, _sequence}},
/// `json` {topic: [text, ...]}, `other` {topic: count}, `schemas` {topic: (name, encoding)},
/// `metadata` {name: {key: value}}, `profile`, `library`.
#[pyfunction]
pub fn read_mcap_raw<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    // The CLI's reader of logs (`diagnose --data`): a regular file of at most 10 000 MB (a
    // FIFO, /dev/zero or a directory is refused without blocking), every chunk checked
    // (sizes, decompression bounded by its claimed size, CRC, inner framing) before the
    // `mcap` crate sees it.
    if !path.exists() {
        return Err(pyo3::exceptions::PyFileNotFoundError::new_err((
            2,
            format!("MCAP file not found: {}", path.display()),
            path.display().to_string(),
        )));
    }
    let bytes = ehactl_input::read_bounded(&path, ehactl_input::DATA_MAX_BYTES, "MCAP log")
        .map_err(|e| {
            if std::fs::metadata(&path).is_ok_and(|m| !m.is_file()) || e.reason.contains("limit") {
                PyValueError::new_err(e.to_string())
            } else {
                PyOSError::new_err(e.to_string())
            }
        })?;
    let bad = |what: String| PyValueError::new_err(format!("{}: {what}", path.display()));
    if let (_, Some(problem)) = ehactl_log::recover::readable_prefix(&bytes) {
        return Err(bad(format!(
            "not a readable MCAP file: {problem} (a log cut off by a killed run can be rebuilt with `ehactl recover`)"
        )));
    }
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
                        let schema =
                            FlatSchema::parse_ros2msg(topic, &text).map_err(|e| e.to_string())?;
                        let cols = schema
                            .fields
                            .iter()
                            .map(|f| match f.prim {
                                Prim::F64 | Prim::F32 => Col::F(Vec::new()),
                                Prim::I64 | Prim::I32 | Prim::I16 | Prim::I8 => Col::I(Vec::new()),
                                Prim::Bool => Col::B(Vec::new()),
                                _ => Col::U(Vec::new()),
                            })
                            .collect();
                        cdr.insert(
                            topic.clone(),
                            CdrTopic {
                                schema,
                                cols,
                                log_time: Vec::new(),
                                sequence: Vec::new(),
                            },
                        );
                    }
                    let t = cdr.get_mut(topic).expect("inserted above");
                    t.push(&m.data)?;
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
        for (f, col) in t.schema.fields.into_iter().zip(t.cols) {
            let name = f.name;
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
