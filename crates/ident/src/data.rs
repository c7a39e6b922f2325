//! Measured records: the CSV format of docs/design.md and ehactl's own MCAP logs.
//!
//! CSV: header row, SI units; `t` (s) and `u` (valve command, V) required; any of `force` (N),
//! `x` (piston position, m), `p_a`, `p_b` (chamber pressures, Pa), `x_v` (spool, fraction of
//! travel), `ref` (setpoint) optional. Lines starting with `#` are comments. Lab exports are
//! read too: fields may be quoted, a UTF-8 byte-order mark is skipped, the separator is `,`,
//! `;` or tab (detected from the header) and a `;`- or tab-separated file may write decimal
//! commas (`0,25`). Every problem is an error naming the file, row and column; nothing is
//! dropped silently.

use std::fmt;
use std::io::Read;
use std::path::Path;

/// A measured output channel the plant can predict.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ChannelKind {
    /// Rod / load-cell force (N), CSV column `force`.
    Force,
    /// Piston position (m), CSV column `x`.
    Position,
    /// Chamber A pressure (Pa), CSV column `p_a`.
    PressureA,
    /// Chamber B pressure (Pa), CSV column `p_b`.
    PressureB,
    /// Spool position (fraction of full travel), CSV column `x_v`.
    Spool,
}

impl ChannelKind {
    /// Every channel in output order.
    pub const ALL: [ChannelKind; 5] = [
        ChannelKind::Force,
        ChannelKind::Position,
        ChannelKind::PressureA,
        ChannelKind::PressureB,
        ChannelKind::Spool,
    ];

    /// CSV column name.
    pub fn column(self) -> &'static str {
        match self {
            ChannelKind::Force => "force",
            ChannelKind::Position => "x",
            ChannelKind::PressureA => "p_a",
            ChannelKind::PressureB => "p_b",
            ChannelKind::Spool => "x_v",
        }
    }

    /// SI unit.
    pub fn unit(self) -> &'static str {
        match self {
            ChannelKind::Force => "N",
            ChannelKind::Position => "m",
            ChannelKind::PressureA | ChannelKind::PressureB => "Pa",
            ChannelKind::Spool => "-",
        }
    }

    /// Value of this channel in a plant measurement.
    pub fn pick(self, m: &ehactl_plant::Measurements) -> f64 {
        match self {
            ChannelKind::Force => m.force,
            ChannelKind::Position => m.position,
            ChannelKind::PressureA => m.p_a,
            ChannelKind::PressureB => m.p_b,
            ChannelKind::Spool => m.spool,
        }
    }
}

/// One measured output channel.
#[derive(Debug, Clone)]
pub struct Channel {
    /// Which signal.
    pub kind: ChannelKind,
    /// Samples in SI units, one per time stamp.
    pub values: Vec<f64>,
}

/// A measured record, uniformly sampled.
#[derive(Debug, Clone)]
pub struct Record {
    /// Where it came from (file path).
    pub source: String,
    /// Time stamps (s), strictly increasing.
    pub t: Vec<f64>,
    /// Valve command (V); empty for an imposed-motion record ([`Record::imposed_motion`]).
    pub u: Vec<f64>,
    /// Output channels present in the file.
    pub channels: Vec<Channel>,
    /// Setpoint column if present (N or m).
    pub reference: Option<Vec<f64>>,
    /// Sample period (s), median of the time differences.
    pub dt: f64,
    /// Non-fatal findings (printed and written to the report).
    pub warnings: Vec<String>,
    /// The config the record was logged with (the `config` of an ehactl MCAP log's
    /// `/config` message, as `RigConfig::to_json`); `None` for CSV.
    pub logged_config: Option<serde_json::Value>,
    /// Piston velocity (m/s), CSV column `v`, when the record gives it (otherwise an
    /// imposed-motion replay derives it from `x`).
    pub velocity: Option<Vec<f64>>,
    /// Operating inputs the config declares (`[inputs.<name>]`), by column name, in their
    /// declared units (e.g. an MR damper's coil `current` in A).
    pub inputs: Vec<(String, Vec<f64>)>,
}

/// A data file that cannot be used; the message names file, row/column and expectation.
#[derive(Debug, Clone, PartialEq)]
pub struct DataError(pub String);

impl fmt::Display for DataError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for DataError {}

impl Record {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t.len()
    }

    /// True when the record holds no samples.
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }

    /// A displacement-controlled test: the record has the motion `x` and the force but
    /// neither a valve command `u` nor a setpoint `ref`, so the measured motion drives the rod
    /// and the model predicts the force ([`ehactl_plant::imposed`]).
    pub fn imposed_motion(&self) -> bool {
        self.u.is_empty() && self.reference.is_none()
    }

    /// The operating input `name`, if the record carries it.
    pub fn input(&self, name: &str) -> Option<&[f64]> {
        self.inputs
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_slice())
    }

    /// The median of the operating input `name` over the record (its operating point), if
    /// the record carries it.
    pub fn input_median(&self, name: &str) -> Option<f64> {
        let mut s = self.input(name)?.to_vec();
        s.sort_by(f64::total_cmp);
        s.get(s.len() / 2).copied()
    }

    /// The channel of a kind, if measured.
    pub fn channel(&self, kind: ChannelKind) -> Option<&[f64]> {
        self.channels
            .iter()
            .find(|c| c.kind == kind)
            .map(|c| c.values.as_slice())
    }

    /// Samples `range` as a new record (same period; time stamps kept).
    pub fn slice(&self, range: std::ops::Range<usize>) -> Record {
        Record {
            source: self.source.clone(),
            t: self.t[range.clone()].to_vec(),
            u: self
                .u
                .get(range.clone())
                .map_or_else(Vec::new, <[f64]>::to_vec),
            channels: self
                .channels
                .iter()
                .map(|c| Channel {
                    kind: c.kind,
                    values: c.values[range.clone()].to_vec(),
                })
                .collect(),
            reference: self.reference.as_ref().map(|r| r[range.clone()].to_vec()),
            dt: self.dt,
            warnings: Vec::new(),
            logged_config: self.logged_config.clone(),
            velocity: self.velocity.as_ref().map(|v| v[range.clone()].to_vec()),
            inputs: self
                .inputs
                .iter()
                .map(|(n, v)| (n.clone(), v[range.clone()].to_vec()))
                .collect(),
        }
    }

    /// Build from columns, checking time, finiteness and sampling.
    /// `row_offset` maps sample index to the file's line number for messages.
    pub fn from_columns(
        source: &str,
        t: Vec<f64>,
        u: Vec<f64>,
        channels: Vec<Channel>,
        reference: Option<Vec<f64>>,
        row_offset: usize,
    ) -> Result<Record, DataError> {
        let n = t.len();
        if n < 20 {
            return Err(DataError(format!(
                "{source}: {n} samples; expected at least 20 rows of data"
            )));
        }
        let check = |name: &str, v: &[f64]| -> Result<(), DataError> {
            let bad: Vec<usize> = (0..v.len()).filter(|&i| !v[i].is_finite()).collect();
            if let Some(&first) = bad.first() {
                return Err(DataError(format!(
                    "{source}: column `{name}` is not a finite number at line {} (sample {first}){}; \
                     expected SI values in every row — fix or cut these rows, nothing is dropped silently",
                    first + row_offset,
                    if bad.len() > 1 {
                        format!(" and {} more rows", bad.len() - 1)
                    } else {
                        String::new()
                    }
                )));
            }
            Ok(())
        };
        check("t", &t)?;
        check("u", &u)?;
        for c in &channels {
            check(c.kind.column(), &c.values)?;
        }
        if let Some(r) = &reference {
            check("ref", r)?;
        }
        for i in 1..n {
            if t[i] <= t[i - 1] {
                return Err(DataError(format!(
                    "{source}: time is not increasing at line {} (t = {} s after {} s); expected strictly increasing `t` in s",
                    i + row_offset,
                    t[i],
                    t[i - 1]
                )));
            }
        }
        let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
        d.sort_by(f64::total_cmp);
        let dt = d[d.len() / 2];
        for i in 1..n {
            let di = t[i] - t[i - 1];
            if (di - dt).abs() > 0.01 * dt {
                return Err(DataError(format!(
                    "{source}: sampling is not uniform at line {} (Δt = {di} s, median {dt} s); \
                     ehactl replays at a fixed period — resample the record first",
                    i + row_offset
                )));
            }
        }
        Ok(Record {
            source: source.to_string(),
            t,
            u,
            channels,
            reference,
            dt,
            warnings: Vec::new(),
            logged_config: None,
            velocity: None,
            inputs: Vec::new(),
        })
    }
}

/// Load a CSV (any extension but `.mcap`) or an ehactl MCAP log.
pub fn load(path: &Path) -> Result<Record, DataError> {
    load_with(path, &[])
}

/// Whether the record at `path` is a displacement-controlled one (x but neither `u` nor
/// `ref`): for a CSV from its header in the first 64 KiB, for an MCAP file from its first
/// message (`mcap_is_motion_only`); `None` for a file that cannot be read (the full load
/// then reports why).
pub fn is_motion_only(path: &Path) -> Option<bool> {
    if path.extension().and_then(|e| e.to_str()) == Some("mcap") {
        return mcap_is_motion_only(path);
    }
    let meta = std::fs::metadata(path).ok()?;
    if !meta.is_file() {
        return None;
    }
    let mut head = Vec::new();
    std::fs::File::open(path)
        .ok()?
        .take(64 * 1024)
        .read_to_end(&mut head)
        .ok()?;
    let text = String::from_utf8_lossy(&head);
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    let delim = detect_delimiter(text) as char;
    let header = text
        .lines()
        .find(|l| !l.trim().is_empty() && !l.trim_start().starts_with('#'))?;
    let names: Vec<&str> = header
        .split(delim)
        .map(|n| n.trim().trim_matches('"'))
        .collect();
    Some(names.contains(&"x") && !names.contains(&"u") && !names.contains(&"ref"))
}

/// [`is_motion_only`] for an MCAP file, read as a stream up to its first `/control` or
/// [`MEASURED_TOPIC`] message, so that a long log is not loaded twice (the campaign or the
/// session loads it in full): an ehactl log (`/control`) is not; a lab record is when its
/// first sample has `x` but neither `u` nor `ref`. `None` when the file cannot be read or
/// has neither topic. The mcap crate's sans-I/O reader does the framing and decompression.
fn mcap_is_motion_only(path: &Path) -> Option<bool> {
    use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader};
    // Only a regular file is opened here: a FIFO would block the open, a device never end
    // (the full load refuses both with a clear error).
    if !std::fs::metadata(path).ok()?.is_file() {
        return None;
    }
    let mut file = std::fs::File::open(path).ok()?;
    let mut reader = LinearReader::new();
    let mut topics: std::collections::HashMap<u16, String> = Default::default();
    while let Some(event) = reader.next_event() {
        match event.ok()? {
            LinearReadEvent::ReadRequest(need) => {
                let got = file.read(reader.insert(need)).ok()?;
                reader.notify_read(got);
            }
            LinearReadEvent::Record { opcode, data } => {
                match mcap::parse_record(opcode, data).ok()? {
                    mcap::records::Record::Channel(c) => {
                        topics.insert(c.id, c.topic);
                    }
                    mcap::records::Record::Message { header, data } => {
                        match topics.get(&header.channel_id).map(String::as_str) {
                            Some("/control") => return Some(false),
                            Some(MEASURED_TOPIC) => {
                                let obj: serde_json::Map<String, serde_json::Value> =
                                    serde_json::from_slice(&data).ok()?;
                                let has = |k: &str| obj.contains_key(k);
                                return Some(has("x") && !has("u") && !has("ref"));
                            }
                            _ => {}
                        }
                    }
                    _ => {}
                }
            }
        }
    }
    None
}

/// [`load`] for a config that declares the operating inputs `inputs` (column names): a CSV
/// column of that name is read into [`Record::inputs`]; any other column outside the format
/// is an error.
pub fn load_with(path: &Path, inputs: &[String]) -> Result<Record, DataError> {
    let source = path.display().to_string();
    // A regular file of at most DATA_MAX_BYTES (a FIFO or /dev/zero is refused, never
    // read), read as a stream: what is held is the record's columns, not the file.
    let what = if path.extension().and_then(|e| e.to_str()) == Some("mcap") {
        "data (MCAP log)"
    } else {
        "data (CSV)"
    };
    let (file, len) = ehactl_input::open_bounded(path, ehactl_input::DATA_MAX_BYTES, what)
        .map_err(|e| DataError(e.to_string()))?;
    let file = std::io::BufReader::with_capacity(1 << 16, file);
    if what == "data (MCAP log)" {
        mcap_record(&source, file, len, inputs)
    } else {
        csv_stream(&source, file, len, inputs)
    }
}

/// The field separator of a CSV text: `,`, `;` or tab, whichever occurs most often outside
/// quotes in the header line (the first line that is neither blank nor a `#` comment);
/// `,` if none does.
fn detect_delimiter(text: &str) -> u8 {
    let header = text
        .lines()
        .find(|l| !l.trim().is_empty() && !l.trim_start().starts_with('#'))
        .unwrap_or("");
    let mut counts = [(b',', 0usize), (b';', 0), (b'\t', 0)];
    let mut quoted = false;
    for c in header.bytes() {
        if c == b'"' {
            quoted = !quoted;
        } else if !quoted {
            for (d, n) in counts.iter_mut() {
                if c == *d {
                    *n += 1;
                }
            }
        }
    }
    // max_by_key keeps the last maximum: order ties so that `,` wins
    counts.reverse();
    counts
        .iter()
        .max_by_key(|(_, n)| *n)
        .filter(|(_, n)| *n > 0)
        .map_or(b',', |(d, _)| *d)
}

/// Parse one numeric field; `decimal_comma` accepts `1,5` for 1.5 (lab exports separated by
/// `;` or tab). Empty and `nan` are NaN (refused later with their line, see `from_columns`).
fn parse_number(f: &str, decimal_comma: bool) -> Option<f64> {
    if f.is_empty() || f.eq_ignore_ascii_case("nan") {
        return Some(f64::NAN);
    }
    if decimal_comma && f.contains(',') {
        if f.contains('.') || f.matches(',').count() > 1 {
            return None; // thousands separators are ambiguous: refused
        }
        return f.replace(',', ".").parse().ok();
    }
    f.parse().ok()
}

/// Longest line of a CSV file (bytes): a line of 8 numbers in full precision takes about
/// 200 bytes; a longer line is not a data export (a file of NULs, a binary file).
pub const MAX_LINE_BYTES: usize = 64 * 1024;

/// Most bytes of the input quoted in an error message.
const QUOTE_MAX_BYTES: usize = 200;

/// `s` cut to at most `max` bytes (at a character boundary), control characters escaped,
/// with the full length said when cut.
fn quote(s: &str, max: usize) -> String {
    let mut end = s.len().min(max);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    let shown: String = s[..end].escape_debug().collect();
    if end < s.len() {
        format!("{shown}… ({} bytes in all)", s.len())
    } else {
        shown
    }
}

/// Why the [`LineGuard`] stopped reading (the message without the file name).
#[derive(Debug)]
struct Refused(String);

impl fmt::Display for Refused {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Refused {}

/// The bytes of a CSV file on their way to the CSV reader, refused at the first NUL byte or
/// the first line longer than [`MAX_LINE_BYTES`]: a binary file, a file of NULs or a "line"
/// of gigabytes is refused after reading at most one buffer past the bad byte, before the
/// CSV reader builds a record of it.
struct LineGuard<R> {
    inner: R,
    /// Line being read (1-based) and its bytes so far.
    line: usize,
    line_len: usize,
    /// The start of the line being read (at most [`QUOTE_MAX_BYTES`]), for messages.
    start: Vec<u8>,
    /// Bytes read before this line.
    offset: u64,
}

impl<R: Read> LineGuard<R> {
    fn new(inner: R) -> Self {
        LineGuard {
            inner,
            line: 1,
            line_len: 0,
            start: Vec::new(),
            offset: 0,
        }
    }

    /// Check the bytes `b` just read.
    fn check(&mut self, b: &[u8]) -> Result<(), Refused> {
        let expected =
            "expected a CSV text export (header row, then one row of numbers per sample)";
        for &c in b {
            if c == b'\n' {
                self.offset += self.line_len as u64 + 1;
                self.line += 1;
                self.line_len = 0;
                self.start.clear();
                continue;
            }
            if c == 0 {
                return Err(Refused(format!(
                    "line {} has a NUL byte at byte {} of the line (byte {} of the file); {expected}, not a binary file",
                    self.line,
                    self.line_len + 1,
                    self.offset + self.line_len as u64
                )));
            }
            self.line_len += 1;
            if self.start.len() < QUOTE_MAX_BYTES {
                self.start.push(c);
            }
            if self.line_len > MAX_LINE_BYTES {
                return Err(Refused(format!(
                    "line {} is longer than the {MAX_LINE_BYTES} bytes a CSV line may have (reading stopped there); {expected}. It starts with \"{}\"",
                    self.line,
                    quote(&String::from_utf8_lossy(&self.start), QUOTE_MAX_BYTES)
                )));
            }
        }
        Ok(())
    }
}

impl<R: Read> Read for LineGuard<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.check(&buf[..n])
            .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, e))?;
        Ok(n)
    }
}

/// A CSV file of `len` bytes from `file`, read as a stream through a [`LineGuard`]: the
/// separator is detected on its first 64 KiB, then the rows are read into columns.
fn csv_stream(
    source: &str,
    mut file: impl Read + std::io::Seek,
    len: u64,
    inputs: &[String],
) -> Result<Record, DataError> {
    let io = |e: std::io::Error| DataError(format!("{source}: cannot read data (CSV) file: {e}"));
    let mut head = Vec::new();
    (&mut file)
        .take(64 * 1024)
        .read_to_end(&mut head)
        .map_err(io)?;
    let text = String::from_utf8_lossy(&head);
    let delim = detect_delimiter(text.strip_prefix('\u{feff}').unwrap_or(&text));
    file.seek(std::io::SeekFrom::Start(0)).map_err(io)?;
    // A file that grows while it is read is read up to its length when opened.
    csv_record(source, delim, file.take(len), inputs)
}

/// Parse CSV text (see the module doc) with the `csv` crate: RFC 4180 quoting, a UTF-8
/// byte-order mark, `#` comment lines, blank lines; the separator is detected (`,`, `;` or
/// tab, see `detect_delimiter`) and a `;`- or tab-separated file may use a decimal comma.
pub fn parse_csv(source: &str, text: &str) -> Result<Record, DataError> {
    parse_csv_with(source, text, &[])
}

/// [`parse_csv`] with the operating inputs the config declares (see [`load_with`]).
pub fn parse_csv_with(source: &str, text: &str, inputs: &[String]) -> Result<Record, DataError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let delim = detect_delimiter(text);
    csv_record(source, delim, text.as_bytes(), inputs)
}

/// [`parse_csv_with`] of the bytes `input` (a UTF-8 byte-order mark is skipped by the CSV
/// reader), separated by `delim`.
fn csv_record(
    source: &str,
    delim: u8,
    input: impl Read,
    inputs: &[String],
) -> Result<Record, DataError> {
    let mut rdr = csv::ReaderBuilder::new()
        .has_headers(false)
        .delimiter(delim)
        .comment(Some(b'#'))
        .flexible(true)
        .trim(csv::Trim::All)
        .from_reader(LineGuard::new(input));
    let mut records = rdr.records().filter_map(|r| match r {
        // a line of blanks only is skipped like an empty line
        Ok(r) if r.len() == 1 && r[0].is_empty() => None,
        other => Some(other),
    });
    let h = CsvHeader::read(source, delim, &mut records)?;
    let known: Vec<&str> = CSV_FORMAT
        .iter()
        .copied()
        .chain(inputs.iter().map(String::as_str))
        .collect();
    let map = CsvColumns::map(source, &h, &known)?;
    let rows = CsvRows::read(source, &h, &known, records)?;
    let off = rows.first_data_line.unwrap_or(h.line + 1);
    let warnings = check_unknown_columns(source, &h, &known, &rows.numeric, inputs)?;
    let mut cols = rows.cols;
    // Moved, not copied: the format's columns are distinct (and no declared input is named
    // like one, `ehactl_config::inputs::RESERVED_COLUMNS`).
    let channels = map
        .ich
        .iter()
        .map(|&(k, i)| Channel {
            kind: k,
            values: std::mem::take(&mut cols[i]),
        })
        .collect();
    let mut rec = Record::from_columns(
        source,
        std::mem::take(&mut cols[map.it]),
        map.iu
            .map_or_else(Vec::new, |i| std::mem::take(&mut cols[i])),
        channels,
        map.iref.map(|i| std::mem::take(&mut cols[i])),
        off,
    )?;
    rec.warnings.extend(warnings);
    let finite = |name: &str, v: &[f64]| -> Result<(), DataError> {
        match v.iter().position(|x| !x.is_finite()) {
            Some(k) => Err(DataError(format!(
                "{source}: column `{name}` is not a finite number at line {} (sample {k}); expected SI values in every row",
                k + off
            ))),
            None => Ok(()),
        }
    };
    if let Some(i) = h.col("v") {
        finite("v", &cols[i])?;
        rec.velocity = Some(cols[i].clone());
    }
    for name in inputs {
        if let Some(i) = h.col(name) {
            finite(name, &cols[i])?;
            rec.inputs.push((name.clone(), cols[i].clone()));
        }
    }
    Ok(rec)
}

/// The columns of the record format (docs/design.md); with the declared operating inputs,
/// the columns parsed as numbers, each of which may appear once.
const CSV_FORMAT: [&str; 9] = ["t", "u", "force", "x", "p_a", "p_b", "x_v", "ref", "v"];

/// Line of a CSV record in the text (1-based; 0 if unknown).
fn csv_line(r: &csv::StringRecord) -> usize {
    r.position().map_or(0, |p| p.line() as usize)
}

/// A reader error of the `csv` crate, with its line (or the [`LineGuard`]'s refusal).
fn csv_error(source: &str, e: csv::Error) -> DataError {
    if let csv::ErrorKind::Io(io) = e.kind() {
        if let Some(r) = io.get_ref().and_then(|r| r.downcast_ref::<Refused>()) {
            return DataError(format!("{source}: {r}"));
        }
    }
    let at = e
        .position()
        .map_or(String::new(), |p| format!(" at line {}", p.line()));
    DataError(format!("{source}: not a readable CSV file{at}: {e}"))
}

/// The header row of a CSV text and how the rows after it are read.
struct CsvHeader {
    /// Column names, in order.
    names: Vec<String>,
    /// Its line in the text.
    line: usize,
    /// The separator, for messages.
    sep_name: &'static str,
    /// A `;`- or tab-separated file may use a decimal comma.
    decimal_comma: bool,
}

impl CsvHeader {
    /// The first record that is not blank or a comment.
    fn read(
        source: &str,
        delim: u8,
        records: &mut impl Iterator<Item = csv::Result<csv::StringRecord>>,
    ) -> Result<CsvHeader, DataError> {
        let sep_name = match delim {
            b';' => "`;`",
            b'\t' => "tab",
            _ => "`,`",
        };
        let header = records
            .next()
            .transpose()
            .map_err(|e| csv_error(source, e))?
            .ok_or_else(|| DataError(format!("{source}: empty file; expected a CSV header row")))?;
        Ok(CsvHeader {
            names: header.iter().map(|s| s.to_string()).collect(),
            line: csv_line(&header),
            sep_name,
            decimal_comma: delim != b',',
        })
    }

    /// Position of column `n` (the first of that name).
    fn col(&self, n: &str) -> Option<usize> {
        self.names.iter().position(|h| h == n)
    }
}

/// Where the record's columns are in the header.
struct CsvColumns {
    /// Time `t`.
    it: usize,
    /// Valve command `u` (`None`: a displacement-controlled test).
    iu: Option<usize>,
    /// The measured channels present.
    ich: Vec<(ChannelKind, usize)>,
    /// Reference `ref`, if any.
    iref: Option<usize>,
}

impl CsvColumns {
    /// Map the header to the record format: a known column appears once, `t` is required,
    /// and `u` unless the record is a displacement-controlled test.
    fn map(source: &str, h: &CsvHeader, known: &[&str]) -> Result<CsvColumns, DataError> {
        let (names, header_line, sep_name) = (&h.names, h.line, h.sep_name);
        // A column used by diagnose must be named once: which of two `p_a` is the measurement?
        for (j, n) in names.iter().enumerate() {
            if let Some(k) = names[..j].iter().position(|m| m == n) {
                if known.contains(&n.as_str()) {
                    return Err(DataError(format!(
                        "{source}: column `{n}` appears twice in header line {header_line} (columns {} and {}); each of t, u, force, x, p_a, p_b, x_v, ref, v and the declared inputs may appear once",
                        k + 1,
                        j + 1
                    )));
                }
            }
        }
        let col = |n: &str| h.col(n);
        let need = |n: &str, what: &str| {
            col(n).ok_or_else(|| {
                DataError(format!(
                    "{source}: missing required column `{n}` ({what}) in header line {header_line} \
                     ({sep_name}-separated): found [{}]",
                    quote(&names.join(", "), QUOTE_MAX_BYTES)
                ))
            })
        };
        let it = need("t", "time in s")?;
        // `u` is required unless the record is a displacement-controlled test (motion `x` and
        // `force`, no `ref`): then the measured motion drives the rod.
        let motion_only = col("u").is_none() && col("ref").is_none();
        let iu = if motion_only {
            if col("x").is_none() {
                return Err(DataError(format!(
                    "{source}: missing required column `u` (valve command in V) in header line {header_line} ({sep_name}-separated), and no motion `x` (m) of a displacement-controlled test instead: found [{}]; expected `u` (with `ref` for a loop test), or `x` with `force` (N)",
                    quote(&names.join(", "), QUOTE_MAX_BYTES)
                )));
            }
            if col("force").is_none() {
                return Err(DataError(format!(
                    "{source}: missing required column `u` (valve command in V) in header line {header_line}; without it the record is a displacement-controlled test, which needs the load-cell `force` (N) beside `x` (m): found [{}]",
                    quote(&names.join(", "), QUOTE_MAX_BYTES)
                )));
            }
            None
        } else {
            Some(need("u", "valve command in V")?)
        };
        let ich = ChannelKind::ALL
            .iter()
            .filter_map(|k| col(k.column()).map(|i| (*k, i)))
            .collect();
        Ok(CsvColumns {
            it,
            iu,
            ich,
            iref: col("ref"),
        })
    }
}

/// The data rows of a CSV text, by column.
struct CsvRows {
    /// Values of each known column (others stay empty).
    cols: Vec<Vec<f64>>,
    /// Per column: every field a finite number (for columns not in the format).
    numeric: Vec<bool>,
    /// Line of the first data row, if any.
    first_data_line: Option<usize>,
}

impl CsvRows {
    /// Read every row after the header: as many fields as the header, a number in every
    /// known column.
    fn read(
        source: &str,
        h: &CsvHeader,
        known: &[&str],
        records: impl Iterator<Item = csv::Result<csv::StringRecord>>,
    ) -> Result<CsvRows, DataError> {
        let (names, sep_name, decimal_comma) = (&h.names, h.sep_name, h.decimal_comma);
        let mut cols: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
        let mut numeric = vec![true; names.len()];
        let mut first_data_line = None;
        for r in records {
            let r = r.map_err(|e| csv_error(source, e))?;
            let ln = csv_line(&r);
            first_data_line.get_or_insert(ln);
            if r.len() != names.len() {
                return Err(DataError(format!(
                    "{source}: line {ln} has {} fields; the header has {} ({sep_name}-separated)",
                    r.len(),
                    names.len()
                )));
            }
            for (j, f) in r.iter().enumerate() {
                if !known.contains(&names[j].as_str()) {
                    // Not in the format: text (a quoted note) is left aside with a warning, a
                    // numeric column is refused later (an undeclared or misspelt input).
                    numeric[j] &= parse_number(f, decimal_comma).is_some_and(f64::is_finite);
                    continue;
                }
                let v = parse_number(f, decimal_comma).ok_or_else(|| {
                    DataError(format!(
                        "{source}: line {ln}, column `{}`: `{f}` is not a number; expected a decimal number{}",
                        names[j],
                        if decimal_comma {
                            " with `.` or `,` as decimal mark and no thousands separator"
                        } else {
                            " with `.` as decimal mark"
                        }
                    ))
                })?;
                cols[j].push(v);
            }
        }
        Ok(CsvRows {
            cols,
            numeric,
            first_data_line,
        })
    }
}

/// Columns not in the record format: a numeric one is refused (an undeclared or misspelt
/// operating input), text ones are left aside with the returned warning.
fn check_unknown_columns(
    source: &str,
    h: &CsvHeader,
    known: &[&str],
    numeric: &[bool],
    inputs: &[String],
) -> Result<Vec<String>, DataError> {
    let (names, header_line) = (&h.names, h.line);
    let unknown: Vec<usize> = (0..names.len())
        .filter(|j| !known.contains(&names[*j].as_str()))
        .collect();
    if let Some(&j) = unknown.iter().find(|j| numeric[**j]) {
        return Err(DataError(format!(
            "{source}: column `{}` in header line {header_line} holds numbers but is not in the record format (t, u, force, x, p_a, p_b, x_v, ref, v; docs/design.md); {}",
            quote(&names[j], 64),
            if inputs.is_empty() {
                "an operating input (e.g. an MR damper's `current`) must be declared in the config as [inputs.<name>] with its unit; otherwise remove the column".to_string()
            } else {
                format!(
                    "the config declares the operating inputs [{}]; declare another as [inputs.<name>] with its unit, fix a misspelt name, or remove the column",
                    inputs.join(", ")
                )
            }
        )));
    }
    let mut warnings = Vec::new();
    if !unknown.is_empty() {
        warnings.push(format!(
            "{source}: text columns not used by ehactl (not in the documented format, docs/design.md): {}",
            quote(
                &unknown
                    .iter()
                    .map(|j| names[*j].as_str())
                    .collect::<Vec<_>>()
                    .join(", "),
                QUOTE_MAX_BYTES
            )
        ));
    }
    Ok(warnings)
}

/// Read the `/control` channel of an ehactl MCAP log (ROS 2 CDR, see `ehactl_log::record`).
pub fn load_mcap(path: &Path) -> Result<Record, DataError> {
    load_with(path, &[])
}

/// Topic of a lab record in MCAP: one JSON object per sample whose keys are the CSV format's
/// column names (`t`, `x`, `force`, `u`, `ref`, …, and the config's declared inputs), e.g.
/// `{"t": 0.002, "x": 0.0498, "force": 220.9, "current": 1.0}`; `t` (s) may be left out, the
/// message's log time then gives it.
pub const MEASURED_TOPIC: &str = "/measured";

/// [`load_mcap`] on bytes already read (`source` names them in errors), for a config
/// declaring the operating inputs `inputs`: an ehactl log's `/control` channel, or else a lab
/// record's [`MEASURED_TOPIC`] channel under the CSV format's rules (columns, units, inputs,
/// imposed motion).
pub fn parse_mcap_with(source: &str, bytes: &[u8], inputs: &[String]) -> Result<Record, DataError> {
    mcap_record(
        source,
        std::io::Cursor::new(bytes),
        bytes.len() as u64,
        inputs,
    )
}

/// [`parse_mcap_with`] of an MCAP file of `len` bytes read as a stream from `file`
/// (`ehactl_log::mcap_read`): the `/control` channel, or else, read again from the start,
/// the [`MEASURED_TOPIC`] channel.
fn mcap_record(
    source: &str,
    mut file: impl Read + std::io::Seek,
    len: u64,
    inputs: &[String],
) -> Result<Record, DataError> {
    match control_record(source, &mut file, len) {
        Err(e) if e.0.ends_with(NO_CONTROL) => {
            file.seek(std::io::SeekFrom::Start(0))
                .map_err(|e| DataError(format!("{source}: cannot read data (MCAP log): {e}")))?;
            measured_record(source, file, len, inputs)?.ok_or(e)
        }
        r => r,
    }
}

/// End of the error for an MCAP file with neither an ehactl log nor a lab record.
const NO_CONTROL: &str = "no /control messages; expected an MCAP log written by `ehactl run`, or a lab record with JSON samples on /measured (DIAGNOSIS.md, \"Campaigns\")";

/// The error of a stream read of an MCAP file (`ehactl_log::mcap_read`).
fn mcap_error(source: &str, e: ehactl_log::mcap_read::ReadError<DataError>) -> DataError {
    match e {
        ehactl_log::mcap_read::ReadError::Mcap(why) => DataError(format!(
            "{source}: not a readable MCAP file: {why} (a log cut off by a killed run can be rebuilt with `ehactl recover`)"
        )),
        ehactl_log::mcap_read::ReadError::Stop(e) => e,
    }
}

/// The CSV text made of the [`MEASURED_TOPIC`] messages, read by the CSV reader as it is
/// made: the reader's end of a bounded channel of text pieces.
struct TextPipe {
    rx: std::sync::mpsc::Receiver<Vec<u8>>,
    buf: Vec<u8>,
    pos: usize,
}

impl Read for TextPipe {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        while self.pos == self.buf.len() {
            match self.rx.recv() {
                Ok(b) => (self.buf, self.pos) = (b, 0),
                Err(_) => return Ok(0), // the maker is done
            }
        }
        let n = out.len().min(self.buf.len() - self.pos);
        out[..n].copy_from_slice(&self.buf[self.pos..self.pos + n]);
        self.pos += n;
        Ok(n)
    }
}

/// A lab record's [`MEASURED_TOPIC`] messages read under the CSV format's rules: their CSV
/// text ([`measured_as_csv`]) goes to the CSV reader in pieces of 64 KiB through a bounded
/// channel, so the text is never held whole. `None` when the topic has no messages.
fn measured_record(
    source: &str,
    file: impl Read,
    len: u64,
    inputs: &[String],
) -> Result<Option<Record>, DataError> {
    let (tx, rx) = std::sync::mpsc::sync_channel::<Vec<u8>>(4);
    let csv_source = format!("{source} ({MEASURED_TOPIC})");
    std::thread::scope(|sc| {
        let pipe = TextPipe {
            rx,
            buf: Vec::new(),
            pos: 0,
        };
        let parser = sc.spawn(|| csv_record(&csv_source, b',', pipe, inputs));
        let made = measured_as_csv(source, file, len, tx);
        let parsed = parser.join().unwrap_or_else(|_| {
            Err(DataError(format!(
                "{csv_source}: the CSV reader stopped unexpectedly"
            )))
        });
        match made {
            Err(e) => Err(e),
            Ok(false) => Ok(None),
            Ok(true) => parsed.map(Some),
        }
    })
}

/// The [`MEASURED_TOPIC`] messages of an MCAP file as CSV text (header: the first message's
/// keys), sent to `tx` in pieces; whether the topic has messages. A message that is not a
/// JSON object of finite numbers with the first message's keys is an error naming its
/// sequence. Stops early, without error, when the reader at the other end has stopped (its
/// error is the one to report).
fn measured_as_csv(
    source: &str,
    file: impl Read,
    len: u64,
    tx: std::sync::mpsc::SyncSender<Vec<u8>>,
) -> Result<bool, DataError> {
    use ehactl_log::mcap_read::Item;
    use std::fmt::Write;
    let mut names: Vec<String> = Vec::new();
    let mut text = String::new();
    let mut reader_stopped = false;
    let read = ehactl_log::mcap_read::for_each(file, len, |item| {
        let Item::Message {
            channel,
            sequence,
            log_time,
            data,
        } = item
        else {
            return Ok(());
        };
        if channel.topic != MEASURED_TOPIC {
            return Ok(());
        }
        let at = format!("{source}: {MEASURED_TOPIC} message (MCAP sequence {sequence})");
        let obj: serde_json::Map<String, serde_json::Value> = serde_json::from_slice(data)
            .map_err(|e| DataError(format!("{at}: not a JSON object of samples: {e}")))?;
        if names.is_empty() {
            names = obj.keys().cloned().collect();
            let has_t = names.iter().any(|n| n == "t");
            let header: Vec<&str> = (!has_t)
                .then_some("t")
                .into_iter()
                .chain(names.iter().map(String::as_str))
                .collect();
            text.push_str(&header.join(","));
            text.push('\n');
        }
        if obj.len() != names.len() || names.iter().any(|n| !obj.contains_key(n)) {
            let keys: Vec<&String> = obj.keys().collect();
            return Err(DataError(format!(
                "{at}: keys {keys:?}; expected those of the first message, {names:?}"
            )));
        }
        if !names.iter().any(|n| n == "t") {
            // Log time in ns → s.
            let _ = write!(text, "{:?},", log_time as f64 * 1e-9);
        }
        for (i, n) in names.iter().enumerate() {
            let v = obj[n].as_f64().filter(|v| v.is_finite()).ok_or_else(|| {
                DataError(format!(
                    "{at}: `{n}` is {}; expected a finite number (SI units)",
                    obj[n]
                ))
            })?;
            let _ = write!(text, "{}{v:?}", if i == 0 { "" } else { "," });
        }
        text.push('\n');
        if text.len() >= 1 << 16 && tx.send(std::mem::take(&mut text).into_bytes()).is_err() {
            reader_stopped = true;
            return Err(DataError(String::new()));
        }
        Ok(())
    });
    if reader_stopped {
        return Ok(true);
    }
    read.map_err(|e| mcap_error(source, e))?;
    let _ = tx.send(text.into_bytes());
    Ok(!names.is_empty())
}

/// [`parse_mcap_with`] for an ehactl log's `/control` channel only.
pub fn parse_mcap(source: &str, bytes: &[u8]) -> Result<Record, DataError> {
    control_record(source, bytes, bytes.len() as u64)
}

/// The columns of an ehactl log's `/control` channel, decoded message by message.
#[derive(Default)]
struct ControlColumns {
    t: Vec<f64>,
    command: Vec<f64>,
    setpoint: Vec<f64>,
    /// force, position, p_a, p_b, spool.
    meas: [Vec<f64>; 5],
}

impl ControlColumns {
    fn push(&mut self, r: &ehactl_log::record::CycleRecord) {
        self.t.push(r.t);
        self.command.push(r.command);
        self.setpoint.push(r.setpoint);
        let m = &r.meas;
        for (c, v) in self
            .meas
            .iter_mut()
            .zip([m.force, m.position, m.p_a, m.p_b, m.spool])
        {
            c.push(v);
        }
    }
}

/// The measured channels of a log (force, position, p_a, p_b, spool): a channel that is
/// NaN throughout is left out (the backend had no such sensor), one with some non-finite
/// samples too, with a warning.
fn logged_channels(source: &str, meas: [Vec<f64>; 5]) -> (Vec<Channel>, Vec<String>) {
    let kinds = [
        ChannelKind::Force,
        ChannelKind::Position,
        ChannelKind::PressureA,
        ChannelKind::PressureB,
        ChannelKind::Spool,
    ];
    // How the record is replayed (the recorded `u`, or the config's PD / PI loop on `ref`) is
    // the session's choice and stated in its notes, not here.
    let mut warnings = Vec::new();
    let mut channels = Vec::new();
    for (k, v) in kinds.into_iter().zip(meas) {
        let nan = v.iter().filter(|x| !x.is_finite()).count();
        if nan == v.len() {
            continue; // the backend did not have this sensor (NaN by convention)
        }
        if nan > 0 {
            warnings.push(format!(
                "{source}: channel {} has {nan} non-finite samples of {}; channel not used",
                k.column(),
                v.len()
            ));
            continue;
        }
        channels.push(Channel { kind: k, values: v });
    }
    (channels, warnings)
}

/// [`parse_mcap`] of an MCAP file of `len` bytes read as a stream from `file`.
fn control_record(source: &str, file: impl Read, len: u64) -> Result<Record, DataError> {
    use ehactl_log::mcap_read::Item;
    use ehactl_log::record::CycleRecord;
    let source = source.to_string();
    let mut cols = ControlColumns::default();
    let mut logged_config = None;
    ehactl_log::mcap_read::for_each(file, len, |item| {
        let Item::Message {
            channel,
            sequence,
            data,
            ..
        } = item
        else {
            return Ok(());
        };
        if channel.topic == "/config" {
            // {"toml": …, "config": RigConfig::to_json(), "backend": …} (ehactl_log::logger)
            logged_config = serde_json::from_slice::<serde_json::Value>(data)
                .ok()
                .and_then(|v| v.get("config").cloned());
        } else if channel.topic == "/control" {
            let r = CycleRecord::decode_control(data)
                .map_err(|e| DataError(format!("{source}: {e} (MCAP sequence {sequence})")))?;
            cols.push(&r);
        }
        Ok(())
    })
    .map_err(|e| mcap_error(&source, e))?;
    if cols.t.is_empty() {
        return Err(DataError(format!("{source}: {NO_CONTROL}")));
    }
    let (channels, warnings) = logged_channels(&source, cols.meas);
    let mut rec = Record::from_columns(
        &source,
        cols.t,
        cols.command,
        channels,
        Some(cols.setpoint),
        0,
    )?;
    rec.warnings.extend(warnings);
    rec.logged_config = logged_config;
    Ok(rec)
}

/// Row index and value of the largest |value| (NaN skipped).
fn peak_row(v: &[f64]) -> (usize, f64) {
    v.iter()
        .enumerate()
        .filter(|(_, x)| x.is_finite())
        .fold(
            (0, 0.0),
            |a, (i, &x)| if x.abs() > a.1 { (i, x.abs()) } else { a },
        )
}

/// Check the record against the rig: sample period vs control period, units that look wrong
/// (pressures in bar or MPa, positions in mm). Returns warnings; unit mismatches are errors.
pub fn check_against(
    rec: &Record,
    params: &ehactl_plant::PlantParams,
    control_dt: f64,
) -> Result<Vec<String>, DataError> {
    let mut w = Vec::new();
    let src = &rec.source;
    let ratio = rec.dt / control_dt;
    if !(0.01..=100.0).contains(&ratio) {
        let hint = if ratio > 100.0 {
            "; is `t` in ms or µs? expected s"
        } else {
            "; is `t` in ks or a sample index scaled wrongly? expected s"
        };
        return Err(DataError(format!(
            "{src}: sample period {} s is {ratio:.3e} × the config's control period {control_dt} s (run.control_rate_hz){hint}",
            rec.dt
        )));
    }
    if (rec.dt - control_dt).abs() > 1e-6 * control_dt {
        w.push(format!(
            "{src}: sample period {} s differs from the config's control period {} s; the plant is replayed at the data's period {} s (no resampling)",
            rec.dt, control_dt, rec.dt
        ));
    }
    if rec.channels.is_empty() {
        return Err(DataError(format!(
            "{src}: no output column; expected at least one of force, x, p_a, p_b, x_v"
        )));
    }
    let ps = params.supply.pressure;
    let fs = params.valve.command_full_scale;
    let umax = rec.u.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    if umax > 1.5 * fs {
        w.push(format!(
            "{src}: |u| reaches {umax:.3} V, beyond 1.5 × valve.command_full_scale = {fs} V; check that `u` is in V"
        ));
    }
    for c in &rec.channels {
        let max = c.values.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        match c.kind {
            ChannelKind::PressureA | ChannelKind::PressureB => {
                if max < 1e-2 * ps && max > 0.0 {
                    // The unit that puts the record's peak nearest to ≈ 0.7 × supply.
                    let guess = [("kPa", 1e3), ("psi", 6894.757), ("bar", 1e5), ("MPa", 1e6)]
                        .iter()
                        .min_by(|a, b| {
                            let d = |f: f64| (max * f / (0.7 * ps)).ln().abs();
                            d(a.1).total_cmp(&d(b.1))
                        })
                        .map_or("another unit", |g| g.0);
                    return Err(DataError(format!(
                        "{src}: column `{}` peaks at {max:.4}, which looks like {guess}, not Pa (supply.pressure is {ps:.4e} Pa); convert to Pa",
                        c.kind.column()
                    )));
                }
                if max > 10.0 * ps {
                    let (row, _) = peak_row(&c.values);
                    return Err(DataError(format!(
                        "{src}: column `{}` reaches {max:.4e} Pa at data row {}, more than 10 × supply.pressure {ps:.4e} Pa: not a plausible pressure; check the data and its unit (Pa)",
                        c.kind.column(),
                        row + 1
                    )));
                }
                if max > 3.0 * ps {
                    w.push(format!(
                        "{src}: column `{}` reaches {max:.4e} Pa, more than 3 × supply.pressure {ps:.4e} Pa",
                        c.kind.column()
                    ));
                }
            }
            ChannelKind::Position => {
                let stroke = params.cylinder.stroke;
                if max > 2.0 * stroke && max * 1e-3 <= 2.0 * stroke {
                    return Err(DataError(format!(
                        "{src}: column `x` reaches {max:.4}, which looks like mm, not m (cylinder.stroke is {stroke} m); convert to m"
                    )));
                }
                if max > 2.0 * stroke {
                    return Err(DataError(format!(
                        "{src}: column `x` reaches {max:.4} m, beyond twice cylinder.stroke = {stroke} m"
                    )));
                }
            }
            ChannelKind::Force => {
                let fmax = ps * params.cylinder.area_a.max(params.cylinder.area_b);
                if max > 10.0 * fmax {
                    let (row, _) = peak_row(&c.values);
                    return Err(DataError(format!(
                        "{src}: column `force` reaches {max:.4e} N at data row {}, 10 × more than supply × piston area = {fmax:.4e} N: not a plausible force; check units (N, not mN)",
                        row + 1
                    )));
                } else if max > 0.0 && max < 1e-2 * fmax {
                    w.push(format!(
                        "{src}: column `force` peaks at {max:.4e} N, below 1 % of supply × piston area = {fmax:.4e} N; if it is in kN, convert to N"
                    ));
                }
            }
            ChannelKind::Spool => {
                if max > 1.5 {
                    return Err(DataError(format!(
                        "{src}: column `x_v` reaches {max:.4}; expected a fraction of full spool travel (|x_v| ≤ 1)"
                    )));
                }
            }
        }
    }
    Ok(w)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 25 rows of `t,u,p_a,p_b` with `sep` between fields and `dec` as decimal mark.
    fn rows(sep: &str, dec: &str) -> String {
        let mut s = format!("t{sep}u{sep}p_a{sep}p_b\n");
        for k in 0..25 {
            let f = |x: f64| format!("{x:?}").replace('.', dec);
            s.push_str(&format!(
                "{}{sep}{}{sep}{}{sep}{}\n",
                f(k as f64 * 1e-3),
                f(0.25),
                f(5.0e6 + k as f64),
                f(4.0e6)
            ));
        }
        s
    }

    fn same(a: &Record, b: &Record) {
        assert_eq!(a.t, b.t);
        assert_eq!(a.u, b.u);
        assert_eq!(
            a.channel(ChannelKind::PressureA),
            b.channel(ChannelKind::PressureA)
        );
        assert_eq!(
            a.channel(ChannelKind::PressureB),
            b.channel(ChannelKind::PressureB)
        );
    }

    #[test]
    fn separators_and_decimal_commas_of_lab_exports() {
        let base = parse_csv("a.csv", &rows(",", ".")).unwrap();
        assert_eq!(base.len(), 25);
        assert_eq!(base.u[3], 0.25);
        same(&base, &parse_csv("b.csv", &rows(";", ",")).unwrap());
        same(&base, &parse_csv("c.csv", &rows(";", ".")).unwrap());
        same(&base, &parse_csv("d.csv", &rows("\t", ",")).unwrap());
        // BOM, CRLF, quoted names, spaces around fields
        let quoted = rows(" , ", ".")
            .replace("t , u , p_a , p_b", "\"t\",\"u\",\"p_a\",\"p_b\"")
            .replace('\n', "\r\n");
        same(
            &base,
            &parse_csv("e.csv", &format!("\u{feff}{quoted}")).unwrap(),
        );
    }

    #[test]
    fn german_spreadsheet_export_file() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/lab_export_de.csv");
        let rec = load(&path).unwrap();
        assert_eq!(rec.len(), 25);
        assert_eq!(rec.t[1], 0.001);
        assert_eq!(rec.u[2], 0.12);
        assert_eq!(rec.channel(ChannelKind::PressureA).unwrap()[4], 5_004_000.0);
        assert_eq!(rec.channel(ChannelKind::PressureB).unwrap()[2], 3_999_000.0);
        assert!((rec.dt - 1e-3).abs() < 1e-12);
        // the text column (a quoted `;` inside) is reported as unused, not parsed
        assert!(
            rec.warnings.iter().any(|w| w.contains("Bemerkung")),
            "{:?}",
            rec.warnings
        );
    }

    #[test]
    fn bad_fields_are_clear_errors() {
        // a comma-separated file cannot hold a decimal comma (it would split the field)
        let text = rows(",", ".").replacen("0.25", "\"0,25\"", 1);
        let e = parse_csv("f.csv", &text).unwrap_err().0;
        assert_eq!(
            e,
            "f.csv: line 2, column `u`: `0,25` is not a number; expected a decimal number with `.` as decimal mark"
        );
        // thousands separators are ambiguous in a `;` file
        let text = rows(";", ",").replacen("5000003,0", "5.000.003,0", 1);
        let e = parse_csv("f.csv", &text).unwrap_err().0;
        assert!(
            e.starts_with("f.csv: line 5, column `p_a`: `5.000.003,0` is not a number")
                && e.contains("no thousands separator"),
            "{e}"
        );
        // a row with a field too many names its line and the separator found
        let mut text = rows(";", ",");
        text.push_str("0,025;0,25;1;2;3\n");
        let e = parse_csv("f.csv", &text).unwrap_err().0;
        assert_eq!(
            e,
            "f.csv: line 27 has 5 fields; the header has 4 (`;`-separated)"
        );
        // the header names the separator when `t`/`u` are missing (e.g. a wrong guess)
        let e = parse_csv("f.csv", "time;volts\n0;1\n").unwrap_err().0;
        assert!(
            e.contains("missing required column `t`") && e.contains("`;`-separated"),
            "{e}"
        );
        let e = parse_csv("f.csv", "\u{feff}\n# only a comment\n")
            .unwrap_err()
            .0;
        assert_eq!(e, "f.csv: empty file; expected a CSV header row");
    }

    #[test]
    fn an_overlong_line_is_refused_quoting_a_few_hundred_bytes() {
        // A "header" of 1 MB of NULs (a binary file, /dev/zero copied): refused before the
        // CSV reader builds a record of it, naming the line and quoting at most 200 bytes.
        let text = "\0".repeat(1_000_000);
        let e = parse_csv("z.csv", &text).unwrap_err().0;
        assert!(
            e.starts_with(
                "z.csv: line 1 has a NUL byte at byte 1 of the line (byte 0 of the file)"
            ),
            "{}",
            &e[..200]
        );
        assert!(e.len() < 2_000, "error of {} bytes", e.len());
        // the same for a data line after a good header
        let text = format!("t,u\n0,1\n{}\n", "9".repeat(MAX_LINE_BYTES + 1));
        let e = parse_csv("d.csv", &text).unwrap_err().0;
        assert!(
            e.contains("line 3 is longer than the 65536 bytes")
                && e.contains("starts with \"999")
                && e.len() < 2_000,
            "{e}"
        );
        // a missing column among many quotes a bounded list
        let wide: Vec<String> = (0..5_000).map(|i| format!("c{i}")).collect();
        let e = parse_csv("w.csv", &format!("{}\n", wide.join(",")))
            .unwrap_err()
            .0;
        assert!(
            e.contains("missing required column `t`") && e.len() < 1_000,
            "{e}"
        );
    }

    /// A reader that hands out `head`, then fails the test if it is read again.
    struct ThenPanic(std::io::Cursor<Vec<u8>>);

    impl Read for ThenPanic {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            let n = self.0.read(buf)?;
            assert!(n > 0, "read past the bad bytes");
            Ok(n)
        }
    }

    #[test]
    fn a_nul_byte_or_an_endless_line_stops_the_read_there() {
        // Good rows, then a NUL: refused at it, and the reader is not read again (a 1 GB
        // file of NULs costs one buffer, not 1 GB).
        let mut head = b"t,u\n0,1\n0.001,2\n".to_vec();
        head.extend_from_slice(b"0.002,\0\0\0");
        let e = csv_record("n.csv", b',', ThenPanic(std::io::Cursor::new(head)), &[])
            .unwrap_err()
            .0;
        assert!(
            e.starts_with(
                "n.csv: line 4 has a NUL byte at byte 7 of the line (byte 22 of the file)"
            ),
            "{e}"
        );
        // An endless line (std::io::repeat never ends): refused after MAX_LINE_BYTES.
        let endless = b"t,u\n".chain(std::io::repeat(b'7'));
        let e = csv_record("e.csv", b',', endless, &[]).unwrap_err().0;
        assert!(
            e.starts_with("e.csv: line 2 is longer than the 65536 bytes a CSV line may have"),
            "{e}"
        );
    }

    #[test]
    fn a_file_is_read_as_a_stream_with_its_errors() {
        let dir = std::env::temp_dir().join(format!("ehactl_data_stream_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = dir.join("g.csv");
        std::fs::write(&good, rows(",", ".")).unwrap();
        let text = rows(",", ".");
        same(
            &load(&good).unwrap(),
            &parse_csv(&good.display().to_string(), &text).unwrap(),
        );
        let nul = dir.join("z.csv");
        std::fs::write(&nul, vec![0u8; 1 << 20]).unwrap();
        let e = load(&nul).unwrap_err().0;
        assert!(e.contains("z.csv: line 1 has a NUL byte"), "{e}");
        // An MCAP file that is not one: refused on its first 8 bytes.
        let fake = dir.join("f.mcap");
        std::fs::write(&fake, vec![b'x'; 1 << 20]).unwrap();
        let e = load(&fake).unwrap_err().0;
        assert!(
            e.contains("does not start with the MCAP magic bytes"),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn delimiter_detection() {
        assert_eq!(detect_delimiter("# a, b, c\nt;u;x\n"), b';');
        assert_eq!(detect_delimiter("t\tu\tx\n"), b'\t');
        assert_eq!(detect_delimiter("\"a;b\",t,u\n"), b',');
        assert_eq!(detect_delimiter("t\n"), b',');
    }

    /// A lab record in MCAP: JSON samples on `/measured`, read under the CSV rules (an
    /// imposed-motion record with a declared input); a sample missing a key or holding a
    /// string is an error naming its sequence; a file with neither topic names both.
    #[test]
    fn mcap_measured_channel() {
        let write = |bad: Option<&str>| {
            let mut w = mcap::Writer::new(std::io::Cursor::new(Vec::new())).unwrap();
            let sid = w.add_schema("Sample", "jsonschema", b"{}").unwrap();
            let ch = w
                .add_channel(sid, MEASURED_TOPIC, "json", &Default::default())
                .unwrap();
            for k in 0..20u64 {
                let x = 0.05 + 0.001 * (k as f64 * 0.3).sin();
                let msg = match bad {
                    Some(b) if k == 4 => b.to_string(),
                    _ => format!(
                        r#"{{"x": {x}, "force": {}, "current": 0.5}}"#,
                        10.0 * k as f64
                    ),
                };
                let header = mcap::records::MessageHeader {
                    channel_id: ch,
                    sequence: k as u32,
                    log_time: k * 2_000_000,
                    publish_time: k * 2_000_000,
                };
                w.write_to_known_channel(&header, msg.as_bytes()).unwrap();
            }
            w.finish().unwrap();
            w.into_inner().into_inner()
        };
        let inputs = ["current".to_string()];
        let rec = parse_mcap_with("lab.mcap", &write(None), &inputs).unwrap();
        assert!(rec.imposed_motion());
        assert_eq!(rec.len(), 20);
        assert!((rec.dt - 2e-3).abs() < 1e-12, "{}", rec.dt);
        assert_eq!(rec.channel(ChannelKind::Force).unwrap()[3], 30.0);
        assert_eq!(rec.input_median("current"), Some(0.5));
        let e = parse_mcap_with(
            "lab.mcap",
            &write(Some(r#"{"x": 0.05, "force": 1.0}"#)),
            &inputs,
        )
        .unwrap_err()
        .0;
        assert!(
            e.starts_with("lab.mcap: /measured message (MCAP sequence 4): keys"),
            "{e}"
        );
        let e = parse_mcap_with(
            "lab.mcap",
            &write(Some(r#"{"x": 0.05, "force": "n/a", "current": 0.5}"#)),
            &inputs,
        )
        .unwrap_err()
        .0;
        assert!(
            e.contains("`force` is \"n/a\"; expected a finite number"),
            "{e}"
        );
        let e = parse_mcap_with("lab.mcap", &write(None), &[])
            .unwrap_err()
            .0;
        assert!(e.contains("current"), "undeclared input column named: {e}");
        let empty = {
            let mut w = mcap::Writer::new(std::io::Cursor::new(Vec::new())).unwrap();
            w.finish().unwrap();
            w.into_inner().into_inner()
        };
        let e = parse_mcap_with("lab.mcap", &empty, &[]).unwrap_err().0;
        assert!(
            e.contains("no /control messages") && e.contains("/measured"),
            "{e}"
        );
    }

    /// A lab record of `n` JSON samples on /measured (`msg(k)`), 1 ms apart.
    fn measured_log(n: u64, msg: impl Fn(u64) -> String) -> Vec<u8> {
        let mut w = mcap::Writer::new(std::io::Cursor::new(Vec::new())).unwrap();
        let sid = w.add_schema("Sample", "jsonschema", b"{}").unwrap();
        let ch = w
            .add_channel(sid, MEASURED_TOPIC, "json", &Default::default())
            .unwrap();
        for k in 0..n {
            let header = mcap::records::MessageHeader {
                channel_id: ch,
                sequence: k as u32,
                log_time: k * 1_000_000,
                publish_time: k * 1_000_000,
            };
            w.write_to_known_channel(&header, msg(k).as_bytes())
                .unwrap();
        }
        w.finish().unwrap();
        w.into_inner().into_inner()
    }

    #[test]
    fn a_long_lab_record_streams_through_the_csv_reader() {
        // 20 000 samples: about 0.9 MB of CSV text, handed over in 64 KiB pieces.
        let good = |k: u64| format!(r#"{{"x": {}, "force": {}}}"#, 0.05 + 1e-6 * k as f64, k);
        let rec = parse_mcap_with("lab.mcap", &measured_log(20_000, good), &[]).unwrap();
        assert_eq!(rec.len(), 20_000);
        let force = rec.channel(ChannelKind::Force).unwrap();
        assert!(force.iter().enumerate().all(|(k, &f)| f == k as f64));
        assert_eq!(rec.t[19_999], 19_999_000_000.0 * 1e-9); // log time (ns) in s
                                                            // A bad message late in the file: its error, though the reader has rows already.
        let late = |k: u64| match k {
            15_000 => r#"{"x": 0.05}"#.to_string(),
            _ => good(k),
        };
        let e = parse_mcap_with("lab.mcap", &measured_log(20_000, late), &[])
            .unwrap_err()
            .0;
        assert!(
            e.starts_with("lab.mcap: /measured message (MCAP sequence 15000): keys"),
            "{e}"
        );
        // The reader refuses the header at once: its error, and the rest is not made.
        let no_motion = |k: u64| format!(r#"{{"foo": {k}}}"#);
        let e = parse_mcap_with("lab.mcap", &measured_log(20_000, no_motion), &[])
            .unwrap_err()
            .0;
        assert!(
            e.starts_with("lab.mcap (/measured): missing required column `u`"),
            "{e}"
        );
    }

    /// An MCAP log's `/control` channel read through the hal decoder (no offsets here);
    /// a message cut short is a clear error naming the file.
    #[test]
    fn mcap_control_channel() {
        use ehactl_log::record::{control_schema, CycleRecord};
        let write = |cut: bool| {
            let mut w = mcap::Writer::new(std::io::Cursor::new(Vec::new())).unwrap();
            let sid = w
                .add_schema(
                    "ehactl_msgs/msg/ControlCycle",
                    "ros2msg",
                    control_schema().as_bytes(),
                )
                .unwrap();
            let ch = w
                .add_channel(sid, "/control", "cdr", &Default::default())
                .unwrap();
            let mut buf = Vec::new();
            for k in 0..30u64 {
                let t = k as f64 * 2e-4;
                let mut r = CycleRecord {
                    cycle: k,
                    t,
                    setpoint: 100.0,
                    command: 0.5 + t,
                    ..Default::default()
                };
                r.meas.force = 90.0 + k as f64;
                r.encode_control(&mut buf);
                if cut && k == 7 {
                    buf.truncate(100);
                }
                let header = mcap::records::MessageHeader {
                    channel_id: ch,
                    sequence: k as u32,
                    log_time: k * 200_000,
                    publish_time: k * 200_000,
                };
                w.write_to_known_channel(&header, &buf).unwrap();
            }
            w.finish().unwrap();
            w.into_inner().into_inner()
        };
        let rec = parse_mcap("run.mcap", &write(false)).unwrap();
        assert_eq!(rec.len(), 30);
        assert_eq!(rec.u[10], 0.5 + 10.0 * 2e-4);
        assert_eq!(rec.reference.as_ref().unwrap()[3], 100.0);
        assert_eq!(rec.channel(ChannelKind::Force).unwrap()[5], 95.0);
        assert!(
            rec.channel(ChannelKind::Position).is_none(),
            "all-NaN channel left out"
        );
        let e = parse_mcap("run.mcap", &write(true)).unwrap_err().0;
        assert_eq!(
            e,
            "run.mcap: /control message of 100 bytes; expected 140 (4-byte CDR header + fields of its schema) (MCAP sequence 7)"
        );
    }
}
