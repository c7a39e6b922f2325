//! Checks of loaded records that `ehactl predict`, a campaign and a single diagnosis share:
//! a channel that cannot be scored (constant), an operating input that is not one operating
//! point (varies within the record) or is missing, and one recording given twice.

use crate::data::{ChannelKind, Record};
use crate::replay::std;
use ehactl_config::RigConfig;
use std::ops::Range;

/// Share of an operating input's level (the larger of |5th|, |95th| percentile and the
/// config's `value`) that its 5th–95th percentile spread may reach within one record (-).
pub const INPUT_LEVEL_TOLERANCE: f64 = 0.05;

/// Multiple of an operating input's sample-to-sample noise (standard deviation) that its
/// 5th–95th percentile spread may reach within one record (-): a measured coil current
/// (noise σ) spreads about 3.3 σ between those percentiles.
pub const INPUT_NOISE_TOLERANCE: f64 = 5.0;

/// Relative size, to a channel's largest |value|, of a standard deviation that is only the
/// rounding of the numbers as written (-): a CSV export prints 6 to 17 significant digits.
pub const ROUNDING_STD: f64 = 1e-9;

/// The channels of `rec` scored over samples `r` (only the force when `imposed`) that cannot
/// be scored, since an NRMSE divides by their standard deviation there: zero, at most
/// [`ROUNDING_STD`] of the largest |value|, or (for `x`) at most half
/// `sensors.position.resolution` (one count of flicker). Each with what it is:
/// "`{src}: column `force` is constant over samples a..b (standard deviation …)`".
pub fn unscorable(
    rec: &Record,
    imposed: bool,
    r: Range<usize>,
    plant: &ehactl_plant::PlantParams,
) -> Vec<(ChannelKind, String)> {
    let mut out = Vec::new();
    for c in &rec.channels {
        if imposed && c.kind != ChannelKind::Force {
            continue;
        }
        let y = &c.values[r.clone()];
        let q = match c.kind {
            ChannelKind::Position => plant.sensors.position.resolution,
            _ => 0.0,
        };
        let s = std(y);
        let peak = y.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        if s == 0.0 || s <= ROUNDING_STD * peak || s <= 0.5 * q {
            let why = if s == 0.0 {
                "zero: every sample the same".to_string()
            } else if s <= 0.5 * q {
                format!("not above half the position resolution {q:e} m")
            } else {
                format!("{ROUNDING_STD:e} of its largest value: rounding only")
            };
            out.push((
                c.kind,
                format!(
                    "{}: column `{}` is constant over samples {}..{} (standard deviation {s:.3e} {}, {why})",
                    rec.source,
                    c.kind.column(),
                    r.start,
                    r.end,
                    c.kind.unit()
                ),
            ));
        }
    }
    out
}

/// Why a constant channel cannot be scored (the end of the messages about one).
pub const CANNOT_SCORE: &str = "a prediction error is normalised by the measured standard deviation, so a constant channel cannot be scored";

/// Refuse a record with a channel that cannot be scored over samples `r` ([`unscorable`]).
pub fn scorable(
    rec: &Record,
    imposed: bool,
    r: Range<usize>,
    plant: &ehactl_plant::PlantParams,
) -> Result<(), String> {
    match unscorable(rec, imposed, r, plant).first() {
        Some((_, what)) => Err(format!(
            "{what}; {CANNOT_SCORE}: give a record in which it varies"
        )),
        None => Ok(()),
    }
}

/// Check each operating input `cfg` declares against `rec`: one that varies within the record
/// (5th–95th percentile spread beyond [`INPUT_LEVEL_TOLERANCE`] of its level and
/// [`INPUT_NOISE_TOLERANCE`] × its noise) is an error, since the model is taken at one
/// operating point per record; one the record lacks gives the returned warning (the config's
/// `value` is taken).
pub fn operating_inputs(cfg: &RigConfig, rec: &Record) -> Result<Vec<String>, String> {
    let mut warnings = Vec::new();
    for (name, inp) in &cfg.inputs {
        let Some(v) = rec.input(name) else {
            warnings.push(format!(
                "{}: no `{name}` column; taken at the config's operating point {} {}",
                rec.source, inp.value, inp.unit
            ));
            continue;
        };
        let mut s = v.to_vec();
        s.sort_by(f64::total_cmp);
        let pct = |p: f64| s[((p * (s.len() - 1) as f64).round() as usize).min(s.len() - 1)];
        let (lo, hi) = (pct(0.05), pct(0.95));
        let level = lo.abs().max(hi.abs()).max(inp.value.abs());
        let tol = (INPUT_LEVEL_TOLERANCE * level).max(INPUT_NOISE_TOLERANCE * noise_std(v));
        if hi - lo > tol {
            return Err(format!(
                "{}: operating input `{name}` varies within the record: {lo} … {hi} {} (5th to 95th percentile; tolerated {tol:.3e} {}: {:.0} % of its level or {INPUT_NOISE_TOLERANCE} × its sample-to-sample noise); the model is taken at one operating point per record: split the record into one per operating point",
                rec.source,
                inp.unit,
                inp.unit,
                100.0 * INPUT_LEVEL_TOLERANCE
            ));
        }
    }
    Ok(warnings)
}

/// Noise standard deviation of a signal from its successive differences: the median absolute
/// difference × 1.4826 (σ of a normal variable from its MAD) / √2 (a difference of two
/// samples). Steps and slow drifts leave the median of the differences near zero.
fn noise_std(v: &[f64]) -> f64 {
    let mut d: Vec<f64> = v.windows(2).map(|w| (w[1] - w[0]).abs()).collect();
    if d.is_empty() {
        return 0.0;
    }
    d.sort_by(f64::total_cmp);
    d[d.len() / 2] * 1.4826 / std::f64::consts::SQRT_2
}

/// Refuse two of `recs` whose parsed samples are identical (time stamps, command, setpoint,
/// channels, velocity and inputs: a copy of one file, also with another encoding, line ending
/// or separator), naming both files: each record of a campaign must be another recording.
pub fn distinct(recs: &[&Record]) -> Result<(), String> {
    let digests: Vec<u64> = recs.iter().map(|r| digest(r)).collect();
    for (i, a) in recs.iter().enumerate() {
        if let Some(b) = (0..i).find(|&j| digests[j] == digests[i] && same_samples(recs[j], a)) {
            return Err(format!(
                "{} and {} hold the same samples ({} of them, identical after parsing); each record of a campaign must be another recording",
                recs[b].source,
                a.source,
                a.len()
            ));
        }
    }
    Ok(())
}

/// Hash of a record's parsed samples (not of its source name).
fn digest(r: &Record) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::hash::DefaultHasher::new();
    let mut col = |v: &[f64]| {
        v.len().hash(&mut h);
        v.iter().for_each(|x| x.to_bits().hash(&mut h));
    };
    col(&r.t);
    col(&r.u);
    col(r.reference.as_deref().unwrap_or(&[]));
    col(r.velocity.as_deref().unwrap_or(&[]));
    for c in &r.channels {
        col(&c.values);
    }
    for (_, v) in &r.inputs {
        col(v);
    }
    for c in &r.channels {
        c.kind.column().hash(&mut h);
    }
    for (n, _) in &r.inputs {
        n.hash(&mut h);
    }
    h.finish()
}

/// Whether `a` and `b` hold the same samples (bit for bit).
fn same_samples(a: &Record, b: &Record) -> bool {
    let eq = |x: &[f64], y: &[f64]| {
        x.len() == y.len() && x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits())
    };
    eq(&a.t, &b.t)
        && eq(&a.u, &b.u)
        && a.reference.as_deref() == b.reference.as_deref()
        && a.velocity.as_deref() == b.velocity.as_deref()
        && a.channels.len() == b.channels.len()
        && a.channels
            .iter()
            .zip(&b.channels)
            .all(|(c, d)| c.kind == d.kind && eq(&c.values, &d.values))
        && a.inputs.len() == b.inputs.len()
        && a.inputs
            .iter()
            .zip(&b.inputs)
            .all(|((n, v), (m, w))| n == m && eq(v, w))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The MTS rig with its MR damper (`[inputs.current]`, unit A, value 0).
    fn mts() -> RigConfig {
        RigConfig::from_toml_str(include_str!("../../../configs/utfsm_mts_mrdamper.toml")).unwrap()
    }

    /// A 500 Hz record of x, force and `current` (when given), named `src`.
    fn record(
        src: &str,
        force: impl Fn(usize) -> f64,
        current: Option<&dyn Fn(usize) -> f64>,
    ) -> Record {
        let mut text = String::from(if current.is_some() {
            "t,x,force,current\n"
        } else {
            "t,x,force\n"
        });
        for k in 0..300 {
            let x = 0.05 + 0.002 * (k as f64 * 0.05).sin();
            text += &format!("{},{x},{}", k as f64 * 0.002, force(k));
            if let Some(c) = current {
                text += &format!(",{}", c(k));
            }
            text += "\n";
        }
        crate::data::parse_csv_with(src, &text, &["current".to_string()]).unwrap()
    }

    #[test]
    fn a_constant_force_cannot_be_scored_and_a_varying_one_can() {
        let p = &mts().plant;
        let flat = record("flat.csv", |_| 120.0, None);
        let e = scorable(&flat, true, 0..300, p).unwrap_err();
        assert!(
            e.starts_with("flat.csv: column `force` is constant over samples 0..300"),
            "{e}"
        );
        let varying = record("v.csv", |k| 120.0 + (k % 7) as f64, None);
        assert!(scorable(&varying, true, 0..300, p).is_ok());
        // Constant over the scored part only.
        let step = record("s.csv", |k| if k < 200 { k as f64 } else { 5.0 }, None);
        assert!(scorable(&step, true, 0..300, p).is_ok());
        assert!(scorable(&step, true, 200..300, p)
            .unwrap_err()
            .contains("samples 200..300"));
    }

    #[test]
    fn an_input_stepping_within_a_record_is_refused_and_a_missing_one_warned() {
        let cfg = mts();
        let steps = record("steps.csv", |k| k as f64, Some(&|k| (k / 100) as f64));
        let e = operating_inputs(&cfg, &steps).unwrap_err();
        assert!(
            e.contains("`current` varies within the record: 0 … 2 A"),
            "{e}"
        );
        let one = record("one.csv", |k| k as f64, Some(&|_| 1.0));
        assert_eq!(operating_inputs(&cfg, &one).unwrap(), Vec::<String>::new());
        let none = record("none.csv", |k| k as f64, None);
        assert_eq!(
            operating_inputs(&cfg, &none).unwrap(),
            vec!["none.csv: no `current` column; taken at the config's operating point 0 A"]
        );
    }

    #[test]
    fn the_noise_of_an_alternating_signal_is_its_amplitude_scaled() {
        // Every difference of ±a alternating is 2a: σ = 2a · 1.4826 / √2.
        let v: Vec<f64> = (0..101)
            .map(|k| if k % 2 == 0 { 0.01 } else { -0.01 })
            .collect();
        assert!((noise_std(&v) - 0.02 * 1.4826 / 2f64.sqrt()).abs() < 1e-15);
        // A single step leaves the median difference, and the noise, at zero.
        let s: Vec<f64> = (0..100).map(|k| if k < 50 { 0.0 } else { 2.0 }).collect();
        assert_eq!(noise_std(&s), 0.0);
    }

    #[test]
    fn records_with_the_same_samples_are_one_recording() {
        let a = record("a.csv", |k| k as f64, Some(&|_| 1.0));
        let b = record("b.csv", |k| k as f64, Some(&|_| 1.0));
        let c = record(
            "c.csv",
            |k| if k == 299 { 0.5 } else { k as f64 },
            Some(&|_| 1.0),
        );
        let e = distinct(&[&a, &c, &b]).unwrap_err();
        assert!(
            e.starts_with("a.csv and b.csv hold the same samples (300 of them"),
            "{e}"
        );
        assert!(distinct(&[&a, &c]).is_ok());
    }
}
