//! Measured records: the CSV format of DESIGN.md and ehactl's own MCAP logs.
//!
//! CSV: header row, SI units; `t` (s) and `u` (valve command, V) required; any of `force` (N),
//! `x` (piston position, m), `p_a`, `p_b` (chamber pressures, Pa), `x_v` (spool, fraction of
//! travel), `ref` (setpoint) optional. Lines starting with `#` are comments. Every problem is an
//! error naming the file, row and column; nothing is dropped silently.

use std::fmt;
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
    /// Valve command (V).
    pub u: Vec<f64>,
    /// Output channels present in the file.
    pub channels: Vec<Channel>,
    /// Setpoint column if present (N or m).
    pub reference: Option<Vec<f64>>,
    /// Sample period (s), median of the time differences.
    pub dt: f64,
    /// Non-fatal findings (printed and written to the report).
    pub warnings: Vec<String>,
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
            u: self.u[range.clone()].to_vec(),
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
                     diagnose replays at a fixed period — resample the record first",
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
        })
    }
}

/// Load a CSV (any extension but `.mcap`) or an ehactl MCAP log.
pub fn load(path: &Path) -> Result<Record, DataError> {
    if path.extension().and_then(|e| e.to_str()) == Some("mcap") {
        load_mcap(path)
    } else {
        let text = std::fs::read_to_string(path)
            .map_err(|e| DataError(format!("{}: cannot read data file: {e}", path.display())))?;
        parse_csv(&path.display().to_string(), &text)
    }
}

/// Parse CSV text (see the module doc).
pub fn parse_csv(source: &str, text: &str) -> Result<Record, DataError> {
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
    let (header_line, header) = lines
        .next()
        .ok_or_else(|| DataError(format!("{source}: empty file; expected a CSV header row")))?;
    let names: Vec<String> = header.split(',').map(|s| s.trim().to_string()).collect();
    let col = |n: &str| names.iter().position(|h| h == n);
    let need = |n: &str, what: &str| {
        col(n).ok_or_else(|| {
            DataError(format!(
                "{source}: missing required column `{n}` ({what}) in header line {}: found [{}]",
                header_line + 1,
                names.join(", ")
            ))
        })
    };
    let it = need("t", "time in s")?;
    let iu = need("u", "valve command in V")?;
    let known = ["t", "u", "force", "x", "p_a", "p_b", "x_v", "ref"];
    let mut warnings = Vec::new();
    let unknown: Vec<&String> = names
        .iter()
        .filter(|n| !known.contains(&n.as_str()))
        .collect();
    if !unknown.is_empty() {
        warnings.push(format!(
            "{source}: columns not used by diagnose (not in DESIGN.md's format): {}",
            unknown
                .iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    let ich: Vec<(ChannelKind, usize)> = ChannelKind::ALL
        .iter()
        .filter_map(|k| col(k.column()).map(|i| (*k, i)))
        .collect();
    let iref = col("ref");
    let mut cols: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    let mut first_data_line = None;
    for (ln, line) in lines {
        first_data_line.get_or_insert(ln + 1);
        let fields: Vec<&str> = line.split(',').collect();
        if fields.len() != names.len() {
            return Err(DataError(format!(
                "{source}: line {} has {} fields; the header has {}",
                ln + 1,
                fields.len(),
                names.len()
            )));
        }
        for (j, f) in fields.iter().enumerate() {
            let f = f.trim();
            let v = if f.is_empty() || f.eq_ignore_ascii_case("nan") {
                f64::NAN
            } else {
                f.parse::<f64>().map_err(|_| {
                    DataError(format!(
                        "{source}: line {}, column `{}`: `{f}` is not a number",
                        ln + 1,
                        names[j]
                    ))
                })?
            };
            cols[j].push(v);
        }
    }
    let off = first_data_line.unwrap_or(header_line + 2);
    let channels = ich
        .iter()
        .map(|&(k, i)| Channel {
            kind: k,
            values: cols[i].clone(),
        })
        .collect();
    let mut rec = Record::from_columns(
        source,
        cols[it].clone(),
        cols[iu].clone(),
        channels,
        iref.map(|i| cols[i].clone()),
        off,
    )?;
    rec.warnings.extend(warnings);
    Ok(rec)
}

/// Read the `/control` channel of an ehactl MCAP log (ROS 2 CDR, see `ehactl_hal::record`).
pub fn load_mcap(path: &Path) -> Result<Record, DataError> {
    let source = path.display().to_string();
    let bytes = std::fs::read(path)
        .map_err(|e| DataError(format!("{source}: cannot read MCAP file: {e}")))?;
    parse_mcap(&source, &bytes)
}

/// [`load_mcap`] on bytes already read (`source` names them in errors).
pub fn parse_mcap(source: &str, bytes: &[u8]) -> Result<Record, DataError> {
    use ehactl_hal::record::CycleRecord;
    let source = source.to_string();
    if let (_, Some(problem)) = ehactl_hal::recover::readable_prefix(bytes) {
        return Err(DataError(format!(
            "{source}: not a readable MCAP file: {problem} (a log cut off by a killed run can be rebuilt with `ehactl recover`)"
        )));
    }
    let stream = mcap::MessageStream::new(bytes)
        .map_err(|e| DataError(format!("{source}: not a readable MCAP file: {e}")))?;
    let mut rows: Vec<CycleRecord> = Vec::new();
    for m in stream {
        let m = m.map_err(|e| DataError(format!("{source}: corrupt MCAP record: {e}")))?;
        if m.channel.topic != "/control" {
            continue;
        }
        let r = CycleRecord::decode_control(&m.data)
            .map_err(|e| DataError(format!("{source}: {e} (MCAP sequence {})", m.sequence)))?;
        rows.push(r);
    }
    if rows.is_empty() {
        return Err(DataError(format!(
            "{source}: no /control messages; expected an MCAP log written by `ehactl run`"
        )));
    }
    let col = |f: fn(&CycleRecord) -> f64| rows.iter().map(f).collect::<Vec<f64>>();
    let outs: [(ChannelKind, fn(&CycleRecord) -> f64); 5] = [
        (ChannelKind::Force, |r| r.meas.force),
        (ChannelKind::Position, |r| r.meas.position),
        (ChannelKind::PressureA, |r| r.meas.p_a),
        (ChannelKind::PressureB, |r| r.meas.p_b),
        (ChannelKind::Spool, |r| r.meas.spool),
    ];
    let mut warnings = vec![format!(
        "{source}: closed-loop record read from MCAP; replayed open loop with the recorded valve command"
    )];
    let mut channels = Vec::new();
    for (k, f) in outs {
        let v = col(f);
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
    let mut rec = Record::from_columns(
        &source,
        col(|r| r.t),
        col(|r| r.command),
        channels,
        Some(col(|r| r.setpoint)),
        0,
    )?;
    rec.warnings.extend(warnings);
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
