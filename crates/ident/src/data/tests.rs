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
        e.starts_with("z.csv: line 1 has a NUL byte at byte 1 of the line (byte 0 of the file)"),
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
        e.starts_with("n.csv: line 4 has a NUL byte at byte 7 of the line (byte 22 of the file)"),
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
