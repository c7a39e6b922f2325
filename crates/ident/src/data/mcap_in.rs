//! The MCAP reader: an ehactl log's `/control` channel, or a lab record's JSON samples on
//! [`MEASURED_TOPIC`].

use super::*;

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
pub(super) fn mcap_record(
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
pub(super) const NO_CONTROL: &str = "no /control messages; expected an MCAP log written by `ehactl run`, or a lab record with JSON samples on /measured (DIAGNOSIS.md, \"Campaigns\")";

/// The error of a stream read of an MCAP file (`ehactl_log::mcap_read`).
pub(super) fn mcap_error(
    source: &str,
    e: ehactl_log::mcap_read::ReadError<DataError>,
) -> DataError {
    match e {
        ehactl_log::mcap_read::ReadError::Mcap(why) => DataError(format!(
            "{source}: not a readable MCAP file: {why} (a log cut off by a killed run can be rebuilt with `ehactl recover`)"
        )),
        ehactl_log::mcap_read::ReadError::Stop(e) => e,
    }
}

/// The CSV text made of the [`MEASURED_TOPIC`] messages, read by the CSV reader as it is
/// made: the reader's end of a bounded channel of text pieces.
pub(super) struct TextPipe {
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
pub(super) fn measured_record(
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
pub(super) fn measured_as_csv(
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
pub(super) struct ControlColumns {
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
pub(super) fn logged_channels(source: &str, meas: [Vec<f64>; 5]) -> (Vec<Channel>, Vec<String>) {
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
pub(super) fn control_record(source: &str, file: impl Read, len: u64) -> Result<Record, DataError> {
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
