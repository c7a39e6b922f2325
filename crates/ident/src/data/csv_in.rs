//! The CSV reader: bounded lines, the header, the columns and the rows, each problem an
//! error naming the file, row and column.

use super::*;

/// Longest line of a CSV file (bytes): a line of 8 numbers in full precision takes about
/// 200 bytes; a longer line is not a data export (a file of NULs, a binary file).
pub const MAX_LINE_BYTES: usize = 64 * 1024;

/// Most bytes of the input quoted in an error message.
pub(super) const QUOTE_MAX_BYTES: usize = 200;

/// `s` cut to at most `max` bytes (at a character boundary), control characters escaped,
/// with the full length said when cut.
pub(super) fn quote(s: &str, max: usize) -> String {
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
pub(super) struct Refused(String);

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
pub(super) struct LineGuard<R> {
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
pub(super) fn csv_stream(
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
pub(super) fn csv_record(
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
pub(super) const CSV_FORMAT: [&str; 9] = ["t", "u", "force", "x", "p_a", "p_b", "x_v", "ref", "v"];

/// Line of a CSV record in the text (1-based; 0 if unknown).
pub(super) fn csv_line(r: &csv::StringRecord) -> usize {
    r.position().map_or(0, |p| p.line() as usize)
}

/// A reader error of the `csv` crate, with its line (or the [`LineGuard`]'s refusal).
pub(super) fn csv_error(source: &str, e: csv::Error) -> DataError {
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
pub(super) struct CsvHeader {
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
pub(super) struct CsvColumns {
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
pub(super) struct CsvRows {
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
pub(super) fn check_unknown_columns(
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
