//! Read any ehactl MCAP log into columns as a stream (`ehactl_log::mcap_read`), with the
//! checks of the CLI's reader (a bounded regular file, its magic bytes first, every chunk's
//! sizes, decompression and CRC).
//! CDR channels are decoded from their own `ros2msg` schema text by the log format's one
//! decoder, `ehactl_log::record::FlatSchema` (primitive fields only, CDR alignment relative
//! to the 4-byte encapsulation header), so a log whose messages gain fields still reads;
//! JSON channels are returned as text for Python to parse.

use ehactl_log::mcap_read::{ChannelInfo, Item};
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
    /// Columns for the CDR channel `channel`, from its `ros2msg` schema.
    fn new(channel: &ChannelInfo) -> Result<CdrTopic, String> {
        let topic = &channel.topic;
        let schema = channel
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
        let schema = FlatSchema::parse_ros2msg(topic, &text).map_err(|e| e.to_string())?;
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
        Ok(CdrTopic {
            schema,
            cols,
            log_time: Vec::new(),
            sequence: Vec::new(),
        })
    }

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

/// What [`read_mcap_raw`] collects, by topic.
#[derive(Default)]
struct Columns {
    cdr: BTreeMap<String, CdrTopic>,
    json: BTreeMap<String, Vec<String>>,
    other: BTreeMap<String, u64>,
    schemas: BTreeMap<String, (String, String)>,
    metadata: BTreeMap<String, BTreeMap<String, String>>,
    profile: String,
    library: String,
}

impl Columns {
    /// Take one record of the file.
    fn take(&mut self, item: Item<'_>) -> Result<(), String> {
        let (channel, sequence, log_time, data) = match item {
            Item::Header { profile, library } => {
                self.profile = profile.to_string();
                self.library = library.to_string();
                return Ok(());
            }
            Item::Metadata(md) => {
                self.metadata.insert(md.name.clone(), md.metadata.clone());
                return Ok(());
            }
            Item::Message {
                channel,
                sequence,
                log_time,
                data,
            } => (channel, sequence, log_time, data),
        };
        let topic = &channel.topic;
        if !self.schemas.contains_key(topic) {
            let (sn, se) = channel
                .schema
                .as_ref()
                .map(|s| (s.name.clone(), s.encoding.clone()))
                .unwrap_or_default();
            self.schemas.insert(topic.clone(), (sn, se));
        }
        match channel.message_encoding.as_str() {
            "cdr" => {
                if !self.cdr.contains_key(topic) {
                    self.cdr.insert(topic.clone(), CdrTopic::new(channel)?);
                }
                let t = self.cdr.get_mut(topic).expect("inserted above");
                t.push(data)?;
                t.log_time.push(log_time);
                t.sequence.push(sequence);
            }
            "json" => self
                .json
                .entry(topic.clone())
                .or_default()
                .push(String::from_utf8_lossy(data).into_owned()),
            _ => *self.other.entry(topic.clone()).or_default() += 1,
        }
        Ok(())
    }
}

/// Read an MCAP file: returns dict with `cdr` {topic: {field: array, _log_time, _sequence}},
/// `json` {topic: [text, ...]}, `other` {topic: count}, `schemas` {topic: (name, encoding)},
/// `metadata` {name: {key: value}}, `profile`, `library`.
#[pyfunction]
pub fn read_mcap_raw<'py>(py: Python<'py>, path: PathBuf) -> PyResult<Bound<'py, PyDict>> {
    // The CLI's reader of logs (`diagnose --data`): a regular file of at most
    // `ehactl_input::DATA_MAX_BYTES` (a FIFO, /dev/zero or a directory is refused without
    // blocking), read as a stream (`ehactl_log::mcap_read`): the magic bytes first, then
    // record by record, every chunk checked (sizes, decompression bounded by its declared
    // size, CRC, inner framing) before the `mcap` crate parses its records. What is held is
    // the columns, not the file.
    if !path.exists() {
        return Err(pyo3::exceptions::PyFileNotFoundError::new_err((
            2,
            format!("MCAP file not found: {}", path.display()),
            path.display().to_string(),
        )));
    }
    let (file, len) = ehactl_input::open_bounded(&path, ehactl_input::DATA_MAX_BYTES, "MCAP log")
        .map_err(|e| {
        if std::fs::metadata(&path).is_ok_and(|m| !m.is_file()) || e.reason.contains("limit") {
            PyValueError::new_err(e.to_string())
        } else {
            PyOSError::new_err(e.to_string())
        }
    })?;
    let bad = |what: String| PyValueError::new_err(format!("{}: {what}", path.display()));
    let mut cols = Columns::default();
    py.detach(|| {
        let file = std::io::BufReader::with_capacity(1 << 16, file);
        ehactl_log::mcap_read::for_each(file, len, |item| cols.take(item))
    })
    .map_err(|e| match e {
        ehactl_log::mcap_read::ReadError::Mcap(problem) => bad(format!(
            "not a readable MCAP file: {problem} (a log cut off by a killed run can be rebuilt with `ehactl recover`)"
        )),
        ehactl_log::mcap_read::ReadError::Stop(e) => bad(e),
    })?;
    let Columns {
        cdr,
        json,
        other,
        schemas,
        metadata,
        profile,
        library,
    } = cols;

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
