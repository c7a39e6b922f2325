//! The rig's position loop when its controller is an assumption (DIAGNOSIS.md "Assumed
//! loop").
//!
//! A closed-loop position record without the valve signal (the UTFSM MTS records) is
//! replayed through the config's PD loop acting on the recorded `ref`; the loop's gain, the
//! valve's bandwidth, the loop's transport delay and the valve's null offset are then
//! assumptions. When the config states their uncertainty (`[uncertainty]` keys
//! `effects.valve_dynamics.time_constant` or `.natural_frequency`, `effects.time_delay.delay`,
//! `effects.valve_deadband.zero_offset`), they are identified before anything else, together
//! with the valve's flow gain (with a proportional loop the loop gain is k_p times the valve
//! gain, and only their product is seen below the command limit), on the loop's own output:
//! the position channel, from `ref`. Fitting them on the mean over channels instead let the
//! force channel (NRMSE 0.9 before any effect, the position's 0.08) bend the loop to shape
//! the velocity for the damper force, and the position got worse (MTS 1 A: 0.047 against 0.025
//! for a linear black box). The identified loop is then part of every later model (the refit
//! of the other nominal parameters, the effects, the grey-box law), which no longer move it.

use crate::ctx::{Ctx, Hyp};
use crate::data::ChannelKind;
use crate::fit::base_params;
use crate::replay::{nrmse, Drive};
use ehactl_plant::params::{DeadbandVariant, Uncertainty};
use ehactl_plant::spec::Role;
use ehactl_plant::PlantParams;
use serde::Serialize;

/// Whether `path` is declared with `role` in its `uncertain(…)` (`#[param]` in
/// crates/plant: `role = loop_param` for the `[uncertainty]` keys that mark the loop as an
/// assumption, the valve's bandwidth, the loop's delay, the valve's null offset and dead
/// band; `role = flow_gain` for the valve flow gains, one per flow form, with a
/// proportional loop the loop gain).
pub fn has_role(path: &str, role: Role) -> bool {
    ehactl_plant::spec::params()
        .iter()
        .any(|p| p.path == path && p.uncertain.is_some_and(|u| u.role == role))
}

/// One identified loop parameter.
#[derive(Debug, Clone, Serialize)]
pub struct LoopParam {
    /// Dotted config path.
    pub path: String,
    /// SI unit.
    pub unit: String,
    /// Value the config assumed.
    pub nominal: f64,
    /// Identified value.
    pub identified: f64,
    /// Lower bound of the stated uncertainty.
    pub lo: f64,
    /// Upper bound of the stated uncertainty.
    pub hi: f64,
    /// Whether the identified value ended within 0.5 % of the span from a bound (the range
    /// the config states does not hold the loop: a wrong assumption or a missing effect).
    pub at_bound: bool,
}

/// The identified loop, for the JSON and report.md.
#[derive(Debug, Clone, Serialize)]
pub struct IdentifiedLoop {
    /// Proportional gain of the assumed position loop (`control.pd.kp`, V/m).
    pub kp: f64,
    /// Velocity gain of the loop K_v = k_p · q_max / (u_fs · A_A) (1/s) as configured: q_max
    /// the edge flow at full opening and Δp = p_s/2 (no load), u_fs the command full scale;
    /// the closed loop's bandwidth for an ideal valve (a first-order lag 1/(1 + s/K_v)).
    pub velocity_gain_nominal: f64,
    /// The same with the identified valve gain (1/s).
    pub velocity_gain: f64,
    /// Identified PT1 spool time constant (s), when refit.
    pub valve_time_constant: Option<f64>,
    /// Identified spool natural frequency (rad/s), when refit (order 2).
    pub valve_natural_frequency: Option<f64>,
    /// Corner frequency of the identified spool model (Hz): 1/(2π·T_z) or ω_nv/2π.
    pub valve_corner_frequency: Option<f64>,
    /// Identified transport delay of the valve command (s), when refit.
    pub delay: Option<f64>,
    /// Identified dead band (overlap) per edge of the valve (fraction of travel, -), when refit.
    pub dead_band: Option<f64>,
    /// Identified null offset of the valve (fraction of travel, -), when refit.
    pub null_offset: Option<f64>,
    /// Steady-state position error x − ref (m) the null offset causes in the proportional
    /// loop (it settles where the command cancels the offset).
    pub position_offset: Option<f64>,
    /// Every refit loop parameter.
    pub params: Vec<LoopParam>,
    /// Position NRMSE on the fitting part (-): the assumed loop, the identified one.
    pub nrmse_fit_nominal: f64,
    /// See `nrmse_fit_nominal`.
    pub nrmse_fit: f64,
    /// One line for the report.
    pub text: String,
}

/// Velocity gain K_v = k_p · q_max / (u_fs · A_A) (1/s) of a proportional position loop on
/// plant `p` (see [`IdentifiedLoop::velocity_gain`]).
pub fn velocity_gain(p: &PlantParams, kp: f64) -> f64 {
    let law = ehactl_plant::valve::EdgeLaw::new(p);
    let ps = p.supply.pressure - p.supply.tank_pressure;
    let q_max = law.k * (0.5 * ps).powf(law.n);
    kp * q_max / (p.valve.command_full_scale * p.cylinder.area_a)
}

fn path_of(name: &str) -> &str {
    name.strip_suffix("/nominal").unwrap_or(name)
}

/// Whether the config marks the loop as an assumption (a loop key, [`has_role`], with a nonzero
/// uncertainty) on a closed-loop position replay.
pub fn assumed(nominal: &PlantParams, drive: Drive) -> bool {
    matches!(drive, Drive::PositionPd(_))
        && nominal.uncertainty.iter().any(|(k, u)| {
            has_role(k, Role::Loop)
                && !matches!(u, Uncertainty::Absolute(a) if *a == 0.0)
                && !matches!(u, Uncertainty::Relative(t) if t.trim().trim_end_matches('%').trim().parse::<f64>() == Ok(0.0))
        })
}

/// Identify the assumed loop on the position channel (see the module doc). Returns the
/// set-up with the identified loop in its base parameters, the nominal parameters with the
/// identified loop written in and its uncertainty spent (the later refit leaves it), and the
/// report; unchanged and `None` when the loop is not an assumption or the record has no
/// position channel.
pub(crate) fn identify<'a>(
    ctx: Ctx<'a>,
    nominal: &PlantParams,
    evals_per_param: usize,
) -> (Ctx<'a>, PlantParams, Option<(IdentifiedLoop, Hyp)>) {
    let Drive::PositionPd(gains) = ctx.drive() else {
        return (ctx, nominal.clone(), None);
    };
    let Some(c) = ctx
        .fit_rec()
        .channels
        .iter()
        .position(|ch| ch.kind == ChannelKind::Position)
    else {
        return (ctx, nominal.clone(), None);
    };
    if !assumed(nominal, ctx.drive()) {
        return (ctx, nominal.clone(), None);
    }
    let mut params: Vec<_> = base_params(nominal)
        .into_iter()
        .filter(|p| {
            let path = path_of(&p.name);
            has_role(path, Role::Loop) || has_role(path, Role::FlowGain)
        })
        .collect();
    // The delay first: the fit's coarse 5-point scan runs over the first new parameter, so
    // that the simplex starts from the best delay of the scan (the cost is not convex in it).
    params.sort_by_key(|p| path_of(&p.name) != "effects.time_delay.delay");
    let scan_delay = params
        .first()
        .is_some_and(|p| path_of(&p.name) == "effects.time_delay.delay");
    let h0 = Hyp {
        effects: vec![],
        variants: vec![],
        values: params.iter().map(|p| p.init).collect(),
        params,
    };
    let before = x_error(&ctx, c, ctx.fit_base_params());
    let (h, _) =
        ctx.on_channel(c)
            .fit(h0, if scan_delay { 0 } else { usize::MAX }, evals_per_param);
    let after = x_error(&ctx, c, &h.build(ctx.fit_base_params()));
    // Nominal parameters with the loop written in; its uncertainty is spent.
    let mut loop_nominal = h.build(nominal);
    for p in &h.params {
        loop_nominal.uncertainty.insert(
            path_of(&p.name).to_string(),
            Uncertainty::Relative("0%".into()),
        );
    }
    let report = describe(nominal, &loop_nominal, gains.kp, &h, before, after, false);
    (ctx.with_base(&h), loop_nominal, Some((report, h)))
}

/// Position NRMSE of `p` on the fitting part of `ctx` (channel `c`).
fn x_error(ctx: &Ctx<'_>, c: usize, p: &PlantParams) -> f64 {
    ctx.fit_replay(p)
        .map(|sim| nrmse(ctx.fit_rec(), &sim, 0..ctx.n_fit())[c])
        .unwrap_or(f64::INFINITY)
}

/// The loop identified again with a rod-force law `law` in place (the grey-box extension):
/// the loop was identified with the nominal load, and a valve's flow falls with the load
/// pressure, so a law of 1.1 kN (MTS 1 A: 1.6 MPa of 10.5 MPa per edge) slowed the identified
/// loop and the position got worse (0.020 → 0.032). Refit on the position channel from the
/// identified values within the same bounds; returns the refit loop and the position NRMSE on
/// the fitting part before and after.
pub(crate) fn reidentify(
    ctx: &Ctx<'_>,
    law: &Hyp,
    loop_h: &Hyp,
    evals_per_param: usize,
) -> Option<(Hyp, f64, f64)> {
    if !matches!(ctx.drive(), Drive::PositionPd(_)) {
        return None;
    }
    let c = ctx
        .fit_rec()
        .channels
        .iter()
        .position(|ch| ch.kind == ChannelKind::Position)?;
    let with_law = ctx.frozen(law);
    let before = x_error(&with_law, c, with_law.fit_base_params());
    let (h, _) = with_law
        .on_channel(c)
        .fit(loop_h.clone(), usize::MAX, evals_per_param);
    let after = x_error(&with_law, c, &h.build(with_law.fit_base_params()));
    Some((h, before, after))
}

/// Every refit loop parameter of `h` in its SI unit: nominal and identified value, the
/// stated range and whether it ended on a bound; a factor on a nominal value of `nominal`
/// (`<path>/nominal`) is turned into the value.
fn loop_params(nominal: &PlantParams, h: &Hyp) -> Vec<LoopParam> {
    let unit = |path: &str| {
        ehactl_plant::spec::params()
            .iter()
            .find(|q| q.path == path)
            .map_or("-", |q| q.unit)
            .to_string()
    };
    h.params
        .iter()
        .zip(&h.values)
        .map(|(p, v)| {
            let path = path_of(&p.name);
            let scale = nominal
                .nominal_value(path)
                .filter(|_| p.name.ends_with("/nominal"));
            let (nom, val, lo, hi) = match scale {
                Some(s) => (s, s * v, s * p.lo, s * p.hi),
                None => (p.init, *v, p.lo, p.hi),
            };
            let u = p.to_unit(*v);
            LoopParam {
                path: path.to_string(),
                unit: unit(path),
                nominal: nominal.nominal_value(path).unwrap_or(nom),
                identified: val,
                lo,
                hi,
                at_bound: p.hi > p.lo && !(0.005..=0.995).contains(&u),
            }
        })
        .collect()
}

/// The report of loop `h` (see [`IdentifiedLoop`]): `nominal` the config's parameters,
/// `loop_nominal` with the loop written in, `with_law` whether it was identified again with
/// the grey-box law in place ([`reidentify`]).
pub(crate) fn describe(
    nominal: &PlantParams,
    loop_nominal: &PlantParams,
    kp: f64,
    h: &Hyp,
    before: f64,
    after: f64,
    with_law: bool,
) -> IdentifiedLoop {
    let lp = loop_params(nominal, h);
    let get = |path: &str| lp.iter().find(|q| q.path == path).map(|q| q.identified);
    let tc = get("effects.valve_dynamics.time_constant");
    let wn = get("effects.valve_dynamics.natural_frequency");
    let corner = tc
        .filter(|t| *t > 0.0)
        .map(|t| 1.0 / (2.0 * std::f64::consts::PI * t))
        .or(wn.map(|w| w / (2.0 * std::f64::consts::PI)));
    let delay = get("effects.time_delay.delay");
    let null_offset = get("effects.valve_deadband.zero_offset");
    // Spool offset (overlap variant): no flow at u/u_fs = z₀, so e = ref − x = z₀·u_fs/k_p;
    // amplifier offset: no flow at u/u_fs = −z₀.
    let sign = match loop_nominal
        .effects
        .valve_deadband
        .as_ref()
        .map(|d| d.variant)
    {
        Some(DeadbandVariant::Amplifier) => 1.0,
        _ => -1.0,
    };
    let position_offset = null_offset
        .map(|z| sign * z * loop_nominal.valve.command_full_scale / kp.max(f64::MIN_POSITIVE));
    let kv0 = velocity_gain(nominal, kp);
    let kv = velocity_gain(loop_nominal, kp);
    let mut parts = vec![format!(
        "velocity gain K_v = {kv:.1} 1/s (assumed {kv0:.1} 1/s; k_p = {kp} V/m times the valve gain)"
    )];
    if let Some(t) = tc {
        parts.push(format!(
            "valve time constant {:.2} ms{}",
            t * 1e3,
            corner.map_or(String::new(), |f| format!(" (corner {f:.1} Hz)"))
        ));
    } else if let Some(w) = wn {
        parts.push(format!(
            "valve natural frequency {w:.0} rad/s ({:.1} Hz)",
            w / (2.0 * std::f64::consts::PI)
        ));
    }
    if let Some(d) = delay {
        parts.push(format!("transport delay {:.2} ms", d * 1e3));
    }
    if let Some(o) = get("effects.valve_deadband.overlap") {
        parts.push(format!(
            "valve dead band {:.2} % of travel per edge",
            o * 100.0
        ));
    }
    if let (Some(z), Some(e)) = (null_offset, position_offset) {
        parts.push(format!(
            "valve null offset {:.2} % of travel (steady position error x − ref = {:.1} µm)",
            z * 100.0,
            e * 1e6
        ));
    }
    let bounds: Vec<&str> = lp
        .iter()
        .filter(|q| q.at_bound)
        .map(|q| q.path.as_str())
        .collect();
    let text = format!(
        "Identified loop (the controller is an assumption; fitted on the position channel from `ref`{}): {}; position NRMSE on the fitting part {before:.4} → {after:.4}{}.",
        if with_law { ", again with the grey-box law in place" } else { "" },
        parts.join(", "),
        if bounds.is_empty() {
            String::new()
        } else {
            format!("; on a bound of the stated uncertainty: {}", bounds.join(", "))
        }
    );
    IdentifiedLoop {
        kp,
        velocity_gain_nominal: kv0,
        velocity_gain: kv,
        valve_time_constant: tc,
        valve_natural_frequency: wn,
        valve_corner_frequency: corner,
        delay,
        dead_band: get("effects.valve_deadband.overlap"),
        null_offset,
        position_offset,
        params: lp,
        nrmse_fit_nominal: before,
        nrmse_fit: after,
        text,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The roles declared on the plant's `#[param]` fields are the loop's assumptions (the
    /// valve's bandwidth of either spool order, the delay, the null offset and dead band)
    /// and the three flow forms' gains.
    #[test]
    fn declared_roles() {
        let with = |r: Role| {
            let mut v: Vec<&str> = ehactl_plant::spec::params()
                .iter()
                .map(|p| p.path)
                .filter(|p| has_role(p, r))
                .collect();
            v.sort_unstable();
            v
        };
        assert_eq!(
            with(Role::Loop),
            [
                "effects.time_delay.delay",
                "effects.valve_deadband.overlap",
                "effects.valve_deadband.zero_offset",
                "effects.valve_dynamics.natural_frequency",
                "effects.valve_dynamics.time_constant",
            ]
        );
        assert_eq!(
            with(Role::FlowGain),
            ["valve.area_max", "valve.flow_at_1mpa", "valve.rated_flow"]
        );
    }
}
