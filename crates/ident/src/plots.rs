//! The plots of a diagnosis report, drawn in Rust as SVG with the `plotters` crate (no
//! Python, no fonts needed: the SVG backend writes text elements the viewer renders).
//!
//! - `traces.svg`: command and each channel, measured vs nominal vs extended; held-out part
//!   shaded.
//! - `residual.svg`: nominal and extended residual per channel over time and their Welch
//!   PSD ([`crate::spectrum::welch_segments`]).
//! - `residual_state.svg`: nominal residual against model velocity, command, p_A and x
//!   (the dependence the catalogue's effects leave, docs/design.md).
//! - `frf.svg`: H1 frequency response u → each channel of data, nominal and extended
//!   ([`crate::spectrum::h1_estimate`]).
//! - `validation.svg`: the validation file's traces when one was given.

use crate::data::{ChannelKind, Record};
use crate::replay::Replay;
use crate::spectrum::{h1_estimate, welch_segments};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// Colours: measured black, nominal blue, extended red (matplotlib's C0 / C3).
const MEASURED: RGBColor = RGBColor(0, 0, 0);
const NOMINAL: RGBColor = RGBColor(31, 119, 180);
const EXTENDED: RGBColor = RGBColor(214, 39, 40);
/// The uncertainty band of a prediction (light red).
const BAND: RGBColor = RGBColor(240, 160, 160);
const SHADE: RGBColor = RGBColor(230, 230, 230);
/// At most this many points per scatter panel (evenly decimated): keeps each SVG small.
const MAX_SCATTER: usize = 2500;
/// At most this many points per time-trace line (evenly decimated).
const MAX_LINE: usize = 6000;

type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;
type PlotResult<T> = Result<T, String>;
/// An H1 estimate to draw: frequencies (Hz), H as (re, im), colour, legend label.
type Curve = (Vec<f64>, Vec<(f64, f64)>, RGBColor, &'static str);

fn err<E: std::fmt::Display>(path: &Path) -> impl Fn(E) -> String + '_ {
    move |e| format!("{}: cannot draw plot: {e}", path.display())
}

/// Finite (lo, hi) of the values with 5 % margin; a flat or empty set gets a unit-wide span.
fn span<'a>(vals: impl IntoIterator<Item = &'a f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in vals.into_iter().filter(|v| v.is_finite()) {
        lo = lo.min(*v);
        hi = hi.max(*v);
    }
    if !lo.is_finite() {
        return (-1.0, 1.0);
    }
    let pad = if hi > lo {
        0.05 * (hi - lo)
    } else {
        0.5 * lo.abs().max(1e-12)
    };
    (lo - pad, hi + pad)
}

/// Positive finite (lo, hi) for a log axis (a decade of margin is not added: exact data span).
fn log_span<'a>(vals: impl IntoIterator<Item = &'a f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in vals.into_iter().filter(|v| v.is_finite() && **v > 0.0) {
        lo = lo.min(*v);
        hi = hi.max(*v);
    }
    if !lo.is_finite() {
        return (1e-12, 1.0);
    }
    if hi <= lo {
        return (lo / 10.0, lo * 10.0);
    }
    (lo / 1.5, hi * 1.5)
}

/// Every `step`-th index so that at most `max` points remain.
fn stride(n: usize, max: usize) -> usize {
    n.div_ceil(max.max(1)).max(1)
}

/// (x, y) pairs with both finite, decimated to at most `max`.
fn points(x: &[f64], y: &[f64], max: usize) -> Vec<(f64, f64)> {
    let n = x.len().min(y.len());
    (0..n)
        .step_by(stride(n, max))
        .map(|k| (x[k], y[k]))
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .collect()
}

/// The values with every non-finite sample (a replay after a numerical failure) set to 0, so
/// that one bad sample does not turn a whole spectrum into NaN.
fn finite_or_zero(v: &[f64]) -> Vec<f64> {
    v.iter()
        .map(|x| if x.is_finite() { *x } else { 0.0 })
        .collect()
}

fn label(kind: ChannelKind) -> String {
    format!("{} ({})", kind.column(), kind.unit())
}

/// One time-series panel: `series` = (values, colour, legend label); the samples from
/// `shade_from` on are shaded (held out).
fn time_panel(
    area: &Area,
    path: &Path,
    t: &[f64],
    y_desc: &str,
    x_desc: &str,
    series: &[(&[f64], RGBColor, &str)],
    shade_from: Option<usize>,
) -> PlotResult<()> {
    let (t0, t1) = span(t.iter());
    let (y0, y1) = span(series.iter().flat_map(|s| s.0.iter()));
    let mut chart = ChartBuilder::on(area)
        .margin(6)
        .x_label_area_size(28)
        .y_label_area_size(70)
        .build_cartesian_2d(t0..t1, y0..y1)
        .map_err(err(path))?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .light_line_style(WHITE)
        .draw()
        .map_err(err(path))?;
    if let Some(k) = shade_from.filter(|k| *k < t.len()) {
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(t[k], y0), (t1, y1)],
                SHADE.filled(),
            )))
            .map_err(err(path))?;
    }
    for (v, colour, name) in series {
        let c = *colour;
        chart
            .draw_series(LineSeries::new(points(t, v, MAX_LINE), c.stroke_width(1)))
            .map_err(err(path))?
            .label(*name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], c));
    }
    if series.len() > 1 {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(err(path))?;
    }
    Ok(())
}

/// The residual measured − model of channel `c`.
fn residual(rec: &Record, model: &Replay, c: usize) -> Vec<f64> {
    rec.channels[c]
        .values
        .iter()
        .enumerate()
        .map(|(k, m)| m - model.y[c].get(k).copied().unwrap_or(f64::NAN))
        .collect()
}

/// Welch segment length of the plots: a power of two between 64 and 4096, about a quarter
/// of the record.
fn plot_segment(n: usize) -> usize {
    let target = (n / 4).clamp(64, 4096);
    1usize << (usize::BITS - 1 - target.leading_zeros())
}

fn traces(
    path: &Path,
    rec: &Record,
    nom: &Replay,
    ext: &Replay,
    split: Option<usize>,
) -> PlotResult<()> {
    let rows = rec.channels.len() + usize::from(split.is_some());
    let root = SVGBackend::new(path, (1100, 220 * rows as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(err(path))?;
    let areas = root.split_evenly((rows, 1));
    let mut i = 0;
    let x_desc = if split.is_some() {
        "t (s), shaded: held out"
    } else {
        "t (s), validation file"
    };
    if split.is_some() {
        time_panel(
            &areas[0],
            path,
            &rec.t,
            "u (V)",
            x_desc,
            &[(&rec.u, MEASURED, "command")],
            split,
        )?;
        i = 1;
    }
    for (c, ch) in rec.channels.iter().enumerate() {
        time_panel(
            &areas[i + c],
            path,
            &rec.t,
            &label(ch.kind),
            x_desc,
            &[
                (&ch.values, MEASURED, "measured"),
                (&nom.y[c], NOMINAL, "nominal"),
                (&ext.y[c], EXTENDED, "extended"),
            ],
            split,
        )?;
    }
    root.present().map_err(err(path))
}

fn residuals(path: &Path, rec: &Record, nom: &Replay, ext: &Replay) -> PlotResult<()> {
    let rows = rec.channels.len();
    let root = SVGBackend::new(path, (1200, 240 * rows as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(err(path))?;
    let areas = root.split_evenly((rows, 2));
    let seg = plot_segment(rec.len());
    for (c, ch) in rec.channels.iter().enumerate() {
        let rn = residual(rec, nom, c);
        let re = residual(rec, ext, c);
        time_panel(
            &areas[2 * c],
            path,
            &rec.t,
            &format!("residual {}", label(ch.kind)),
            "t (s)",
            &[(&rn, NOMINAL, "nominal"), (&re, EXTENDED, "extended")],
            None,
        )?;
        let (f, pn) = welch_segments(&finite_or_zero(&rn), rec.dt, seg);
        let (_, pe) = welch_segments(&finite_or_zero(&re), rec.dt, seg);
        let (f0, f1) = log_span(f[1..].iter());
        let (p0, p1) = log_span(pn[1..].iter().chain(&pe[1..]));
        let mut chart = ChartBuilder::on(&areas[2 * c + 1])
            .margin(6)
            .x_label_area_size(28)
            .y_label_area_size(70)
            .build_cartesian_2d(f0..f1, (p0..p1).log_scale())
            .map_err(err(path))?;
        chart
            .configure_mesh()
            .x_desc("f (Hz)")
            .y_desc(format!("PSD ({}²/Hz)", ch.kind.unit()))
            .light_line_style(WHITE)
            .draw()
            .map_err(err(path))?;
        for (p, colour) in [(&pn, NOMINAL), (&pe, EXTENDED)] {
            chart
                .draw_series(LineSeries::new(
                    f.iter()
                        .zip(p.iter())
                        .skip(1)
                        .filter(|(_, v)| **v > 0.0)
                        .map(|(a, b)| (*a, *b)),
                    colour.stroke_width(1),
                ))
                .map_err(err(path))?;
        }
    }
    root.present().map_err(err(path))
}

fn residual_state(path: &Path, rec: &Record, nom: &Replay) -> PlotResult<()> {
    let mut states: Vec<(&[f64], String)> = vec![
        (&nom.v, "model velocity (m/s)".into()),
        (&rec.u, "command u (V)".into()),
    ];
    for kind in [ChannelKind::PressureA, ChannelKind::Position] {
        if let Some(ch) = rec.channels.iter().find(|c| c.kind == kind) {
            states.push((&ch.values, label(kind)));
        }
    }
    let rows = rec.channels.len();
    let cols = states.len();
    let root = SVGBackend::new(path, (300 * cols as u32, 240 * rows as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(err(path))?;
    let areas = root.split_evenly((rows, cols));
    for (c, ch) in rec.channels.iter().enumerate() {
        let rn = residual(rec, nom, c);
        for (j, (x, name)) in states.iter().enumerate() {
            let pts = points(x, &rn, MAX_SCATTER);
            let (x0, x1) = span(pts.iter().map(|p| &p.0));
            let (y0, y1) = span(pts.iter().map(|p| &p.1));
            let mut chart = ChartBuilder::on(&areas[c * cols + j])
                .margin(6)
                .x_label_area_size(28)
                .y_label_area_size(60)
                .build_cartesian_2d(x0..x1, y0..y1)
                .map_err(err(path))?;
            let y_desc = if j == 0 {
                format!("nominal residual {}", ch.kind.column())
            } else {
                String::new()
            };
            chart
                .configure_mesh()
                .x_desc(name.as_str())
                .y_desc(y_desc)
                .light_line_style(WHITE)
                .x_labels(4)
                .draw()
                .map_err(err(path))?;
            chart
                .draw_series(
                    pts.iter()
                        .map(|p| Circle::new(*p, 1, NOMINAL.mix(0.5).filled())),
                )
                .map_err(err(path))?;
        }
    }
    root.present().map_err(err(path))
}

/// The phase of each point of a frequency response (re, im), unwrapped (deg): a jump of
/// more than π between neighbours is taken as a wrap.
fn unwrapped_phase(h: &[(f64, f64)]) -> Vec<f64> {
    let mut out = Vec::with_capacity(h.len());
    let mut prev = 0.0f64;
    let mut offset = 0.0f64;
    for (k, (re, im)) in h.iter().enumerate() {
        let a = im.atan2(*re);
        if k > 0 {
            let d = a - prev;
            if d > std::f64::consts::PI {
                offset -= std::f64::consts::TAU;
            } else if d < -std::f64::consts::PI {
                offset += std::f64::consts::TAU;
            }
        }
        prev = a;
        out.push((a + offset).to_degrees());
    }
    out
}

/// The frequency responses u → each channel (H1 estimates) of the record and the nominal
/// and extended replays: magnitude above, unwrapped phase below, one column per channel.
fn frf(path: &Path, rec: &Record, nom: &Replay, ext: &Replay) -> PlotResult<()> {
    let cols = rec.channels.len();
    let root = SVGBackend::new(path, (360 * cols as u32, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(err(path))?;
    let areas = root.split_evenly((2, cols));
    let seg = plot_segment(rec.len());
    for (c, ch) in rec.channels.iter().enumerate() {
        let curves: Vec<Curve> = [
            (&ch.values, MEASURED, "measured"),
            (&nom.y[c], NOMINAL, "nominal"),
            (&ext.y[c], EXTENDED, "extended"),
        ]
        .into_iter()
        .map(|(y, colour, name)| {
            let (f, h) = h1_estimate(&rec.u, &finite_or_zero(y), rec.dt, seg);
            (f, h, colour, name)
        })
        .collect();
        let f = &curves[0].0;
        let (f0, f1) = log_span(f[1..].iter());
        let mags: Vec<Vec<f64>> = curves
            .iter()
            .map(|cv| cv.1.iter().map(|(re, im)| re.hypot(*im)).collect())
            .collect();
        // Unwrapped phase (deg) so that a delay reads as a straight descent.
        let phases: Vec<Vec<f64>> = curves.iter().map(|cv| unwrapped_phase(&cv.1)).collect();
        let (m0, m1) = log_span(mags.iter().flat_map(|m| m[1..].iter()));
        let mut top = ChartBuilder::on(&areas[c])
            .margin(6)
            .caption(format!("u → {}", ch.kind.column()), ("sans-serif", 14))
            .x_label_area_size(24)
            .y_label_area_size(60)
            .build_cartesian_2d((f0..f1).log_scale(), (m0..m1).log_scale())
            .map_err(err(path))?;
        top.configure_mesh()
            .y_desc(if c == 0 {
                format!("|H| ({}/V)", ch.kind.unit())
            } else {
                String::new()
            })
            .light_line_style(WHITE)
            .draw()
            .map_err(err(path))?;
        for (cv, m) in curves.iter().zip(&mags) {
            let colour = cv.2;
            top.draw_series(LineSeries::new(
                f.iter()
                    .zip(m)
                    .skip(1)
                    .filter(|(_, v)| **v > 0.0 && v.is_finite())
                    .map(|(a, b)| (*a, *b)),
                colour.stroke_width(1),
            ))
            .map_err(err(path))?
            .label(cv.3)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour));
        }
        if c == 0 {
            top.configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(err(path))?;
        }
        let (ph0, ph1) = span(phases.iter().flat_map(|p| p[1..].iter()));
        let mut bottom = ChartBuilder::on(&areas[cols + c])
            .margin(6)
            .x_label_area_size(28)
            .y_label_area_size(60)
            .build_cartesian_2d((f0..f1).log_scale(), ph0..ph1)
            .map_err(err(path))?;
        bottom
            .configure_mesh()
            .x_desc("f (Hz)")
            .y_desc(if c == 0 { "phase (deg)" } else { "" })
            .light_line_style(WHITE)
            .draw()
            .map_err(err(path))?;
        for (cv, p) in curves.iter().zip(&phases) {
            bottom
                .draw_series(LineSeries::new(
                    f.iter().zip(p).skip(1).map(|(a, b)| (*a, *b)),
                    cv.2.stroke_width(1),
                ))
                .map_err(err(path))?;
        }
    }
    root.present().map_err(err(path))
}

/// One panel of a prediction plot: a record's measured channel against the model's
/// prediction (and the nominal model's, when given); samples from `shade_from` on are the
/// scored (held-out) part.
pub struct PredictionPanel<'a> {
    /// Panel title: the record and the channel with its unit.
    pub title: String,
    /// Time stamps (s).
    pub t: &'a [f64],
    /// Measured values.
    pub measured: &'a [f64],
    /// Predicted values.
    pub predicted: &'a [f64],
    /// The nominal model's values, if drawn.
    pub nominal: Option<&'a [f64]>,
    /// First scored sample, if only a part is scored.
    pub shade_from: Option<usize>,
    /// The prediction's uncertainty band (lower, upper), if it has one.
    pub band: Option<(&'a [f64], &'a [f64])>,
}

/// Measured vs predicted, one panel per entry (`ehactl predict`, a campaign's report).
pub fn prediction(path: &Path, panels: &[PredictionPanel<'_>]) -> PlotResult<()> {
    let rows = panels.len().max(1);
    let root = SVGBackend::new(path, (1100, 220 * rows as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(err(path))?;
    let areas = root.split_evenly((rows, 1));
    for (p, area) in panels.iter().zip(&areas) {
        let mut series: Vec<(&[f64], RGBColor, &str)> = vec![(p.measured, MEASURED, "measured")];
        if let Some(n) = p.nominal {
            series.push((n, NOMINAL, "nominal"));
        }
        series.push((p.predicted, EXTENDED, "predicted"));
        if let Some((lo, hi)) = p.band {
            series.push((lo, BAND, "band, lower"));
            series.push((hi, BAND, "band, upper"));
        }
        let x_desc = if p.shade_from.is_some() {
            "t (s), shaded: scored"
        } else {
            "t (s)"
        };
        time_panel(area, path, p.t, &p.title, x_desc, &series, p.shade_from)?;
    }
    root.present().map_err(err(path))
}

/// Draw the report's plots into `out` (each written atomically, [`crate::outdir`]): returns
/// the files written. `split` is the first held-out sample of `rec`; `val` the validation
/// record with its nominal and extended replays. A plot that cannot be drawn is an error
/// naming the file (nothing is skipped silently).
pub fn draw(
    out: &mut crate::outdir::OutDir,
    rec: &Record,
    nom: &Replay,
    ext: &Replay,
    split: usize,
    val: Option<(&Record, &Replay, &Replay)>,
) -> Result<Vec<PathBuf>, String> {
    let made = vec![
        out.write_with("traces.svg", |p| traces(p, rec, nom, ext, Some(split)))?,
        out.write_with("residual.svg", |p| residuals(p, rec, nom, ext))?,
        out.write_with("residual_state.svg", |p| residual_state(p, rec, nom))?,
        out.write_with("frf.svg", |p| frf(p, rec, nom, ext))?,
    ];
    let mut made = made;
    if let Some((v, vn, ve)) = val {
        made.push(out.write_with("validation.svg", |p| traces(p, v, vn, ve, None))?);
    }
    Ok(made)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plot_segment_is_a_power_of_two_near_a_quarter_of_the_record() {
        assert_eq!(plot_segment(8000), 1024);
        assert_eq!(plot_segment(100), 64);
        assert_eq!(plot_segment(1_000_000), 4096);
    }

    #[test]
    fn spans_ignore_non_finite_values_and_widen_flat_ones() {
        let (lo, hi) = span([1.0, f64::NAN, 3.0, f64::INFINITY].iter());
        assert!((lo - 0.9).abs() < 1e-12 && (hi - 3.1).abs() < 1e-12);
        let (lo, hi) = span([2.0, 2.0].iter());
        assert!(lo < 2.0 && hi > 2.0);
        let (lo, hi) = log_span([0.0, -1.0, 1e-3, 10.0].iter());
        assert!(lo > 0.0 && lo < 1e-3 && hi > 10.0);
    }
}
