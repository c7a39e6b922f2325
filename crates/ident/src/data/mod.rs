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

mod csv_in;
mod mcap_in;
#[cfg(test)]
mod tests;

use csv_in::*;
pub use csv_in::{parse_csv, parse_csv_with, MAX_LINE_BYTES};
use mcap_in::*;
pub use mcap_in::{load_mcap, parse_mcap, parse_mcap_with, MEASURED_TOPIC};

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
    let fs = params.valve.command_full_scale;
    let umax = rec.u.iter().fold(0.0f64, |a, v| a.max(v.abs()));
    if umax > 1.5 * fs {
        w.push(format!(
            "{src}: |u| reaches {umax:.3} V, beyond 1.5 × valve.command_full_scale = {fs} V; check that `u` is in V"
        ));
    }
    for c in &rec.channels {
        check_channel(c, src, params, &mut w)?;
    }
    Ok(w)
}

/// Check one channel `c` of record `src` against the rig `params`: a unit that looks wrong
/// is an error, an implausible level a warning pushed to `w`.
fn check_channel(
    c: &Channel,
    src: &str,
    params: &ehactl_plant::PlantParams,
    w: &mut Vec<String>,
) -> Result<(), DataError> {
    let ps = params.supply.pressure;
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
    Ok(())
}
