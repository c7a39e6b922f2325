//! A second hidden-effect generator, written from the physics independently of
//! `crates/plant`, so that the evaluation does not grade the diagnosis on its own model: its own rig, its own equations for every effect
//! and variant, its own fixed-step classical Runge–Kutta (RK4) integrator, its own noise
//! generator and excitation. It shares no code with the plant: only the nominal config it
//! hands to the diagnosis is a [`PlantParams`] (written from the generator's nominal values).
//!
//! Where the plant uses a different structure for the same catalogue effect, the generator
//! deliberately does too: LuGre friction (Canudas de Wit et al. 1995, IEEE TAC 40(3)) instead
//! of the plant's Stribeck + stick projection; a soft (tanh) spool saturation instead of a
//! hard limit; the entrained-air bulk modulus of Yu, Chen & Lu (1994) / Gholizadeh et al.
//! (2011); a pressure-compensated pump with a flow limit; a compliant cylinder mount; a sensor
//! tone with arbitrary phase; an arctan load-side Coulomb force (MR damper / guide); Dahl's
//! (1968) friction with the friction force itself as the state (the plant integrates a
//! LuGre bristle deflection); a compliant hose as one lumped volume at the valve port with the
//! thin-wall bulk modulus and a laminar resistance to the chamber, no inertance (the plant
//! uses its R-L-C segment chain).
//!
//! The cases of the evaluation are listed with their seeds in `bench/indep_cases.txt`
//! (committed before any result was seen).

use ehactl_ident::data::{Channel, ChannelKind, Record};
use ehactl_plant::PlantParams;
use std::f64::consts::{PI, TAU};

/// Generator of uniform and normal numbers: PCG-XSH-RR 32 (O'Neill 2014), two draws per f64.
#[derive(Debug, Clone)]
pub struct Pcg(u64);

impl Pcg {
    /// Seeded.
    pub fn new(seed: u64) -> Self {
        let mut g = Pcg(seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407));
        g.next_u32();
        g
    }
    fn next_u32(&mut self) -> u32 {
        let old = self.0;
        self.0 = old
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }
    /// Uniform in [0, 1).
    pub fn u(&mut self) -> f64 {
        let hi = (self.next_u32() >> 5) as u64;
        let lo = (self.next_u32() >> 6) as u64;
        ((hi << 26) | lo) as f64 / (1u64 << 53) as f64
    }
    /// Uniform in [a, b).
    pub fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.u()
    }
    /// Log-uniform in [a, b).
    pub fn log_range(&mut self, a: f64, b: f64) -> f64 {
        (a.ln() + (b / a).ln() * self.u()).exp()
    }
    /// Standard normal (Marsaglia polar method).
    pub fn normal(&mut self) -> f64 {
        loop {
            let a = 2.0 * self.u() - 1.0;
            let b = 2.0 * self.u() - 1.0;
            let s = a * a + b * b;
            if s > 0.0 && s < 1.0 {
                return a * (-2.0 * s.ln() / s).sqrt();
            }
        }
    }
}

/// Nominal rig of the generator (SI): a 40/28 mm differential cylinder with a 45 kg moving
/// mass on a centring spring, an underlapped 4/3 proportional valve, 14 MPa supply. These are
/// assumptions of a plausible bench (not a paper's rig), different from the plant's test bench.
#[derive(Debug, Clone)]
pub struct Rig {
    /// Supply pressure (Pa).
    pub ps: f64,
    /// Oil density (kg/m³).
    pub rho: f64,
    /// Liquid bulk modulus (Pa).
    pub beta: f64,
    /// Kinematic viscosity (m²/s).
    pub nu: f64,
    /// Rated flow per edge at full opening and `dp_rated` (m³/s).
    pub q_rated: f64,
    /// Pressure drop of the rating (Pa).
    pub dp_rated: f64,
    /// Underlap per edge (fraction of travel).
    pub underlap: f64,
    /// Command for full opening (V).
    pub full_scale: f64,
    /// Piston area A (m²).
    pub aa: f64,
    /// Annulus area B (m²).
    pub ab: f64,
    /// Dead volumes A, B (m³).
    pub va0: f64,
    /// Dead volume B (m³).
    pub vb0: f64,
    /// Stroke (m).
    pub stroke: f64,
    /// Moving mass (kg).
    pub m: f64,
    /// Viscous damping (N·s/m).
    pub c: f64,
    /// Centring spring (N/m), relaxed at mid stroke.
    pub k: f64,
    /// Laminar transition of the edge law (Pa).
    pub dp_lam: f64,
    /// Noise σ: force (N), position (m), pressure (Pa).
    pub noise: (f64, f64, f64),
}

impl Default for Rig {
    fn default() -> Self {
        let a = PI / 4.0 * 0.040f64.powi(2);
        Rig {
            ps: 14.0e6,
            rho: 860.0,
            beta: 1.5e9,
            nu: 32e-6,
            q_rated: 1.2e-4,
            dp_rated: 3.5e6,
            underlap: 0.02,
            full_scale: 10.0,
            aa: a,
            ab: a - PI / 4.0 * 0.028f64.powi(2),
            va0: 6.0e-5,
            vb0: 8.0e-5,
            stroke: 0.25,
            m: 45.0,
            c: 2500.0,
            k: 1.5e6,
            dp_lam: 3.0e4,
            noise: (6.0, 2.0e-6, 2.5e4),
        }
    }
}

/// One hidden effect with its structural variant and parameters (SI; the fields are named in
/// each variant's doc line).
#[derive(Debug, Clone, PartialEq)]
#[allow(missing_docs)]
pub enum Hidden {
    /// LuGre friction (Canudas de Wit 1995): ż = v − σ₀|v|z/g(v), F = σ₀z + σ₁ż,
    /// g = F_C + (F_S − F_C)·exp(−(v/v_s)²).
    LuGre {
        fc: f64,
        fs: f64,
        vs: f64,
        s0: f64,
        s1: f64,
    },
    /// Load-side Coulomb force without stick: F = F_C·(2/π)·atan(v/v_ε) (MR damper, guide).
    LoadCoulomb { fc: f64, veps: f64 },
    /// Dahl's friction (Dahl 1968, "A solid friction model", Aerospace Corp.
    /// TOR-0158(3107-18)-1; exponent i = 1): the force F is the state,
    /// dF/dx = σ₀·(1 − F·sign(ẋ)/F_C), i.e. Ḟ = σ₀·(v − |v|·F/F_C).
    Dahl { fc: f64, s0: f64 },
    /// Compliant hose per side between valve port and chamber: bore `d`, length `len`, wall
    /// thickness `t`, effective wall modulus `e` (thin wall: 1/β_eff = 1/β + d/(t·e), Merritt
    /// 1967 "Hydraulic Control Systems" eq. 2-46), its oil in one lumped volume at the valve
    /// port; a laminar resistance `r` (Hagen–Poiseuille of the hose plus the fittings) to the
    /// chamber, no inertance.
    Hose {
        len: f64,
        d: f64,
        t: f64,
        e: f64,
        r: f64,
    },
    /// Spool overlap `ov` (reduces the underlap) and zero offset (fractions of travel).
    Overlap { ov: f64, offset: f64 },
    /// Dead zone of width `d` (fraction of full scale) in the amplifier ahead of the
    /// underlapped spool, with an amplifier offset.
    AmpDeadzone { d: f64, offset: f64 },
    /// Soft spool saturation s → L·tanh(s/L).
    SoftSaturation { l: f64 },
    /// Asymmetric hard spool limits +lp / −ln.
    AsymSaturation { lp: f64, ln: f64 },
    /// First-order spool, time constant τ (s).
    Spool1 { tau: f64 },
    /// Second-order spool ω_n (rad/s), ζ.
    Spool2 { wn: f64, z: f64 },
    /// Cross-piston laminar leakage (m³/(s·Pa)).
    InternalLeak { k: f64 },
    /// Leakage to tank from both chambers (m³/(s·Pa)).
    ExternalLeakBoth { k: f64 },
    /// Leakage to tank from chamber A only (m³/(s·Pa)).
    ExternalLeakA { k: f64 },
    /// Entrained air (Yu et al. 1994 as reviewed by Gholizadeh et al. 2011): air volume
    /// fraction α₀ at atmospheric pressure, polytropic index n.
    EntrainedAir { alpha0: f64, n: f64 },
    /// β(p) = β₀ + K·p, capped at `max`.
    LinearBeta { slope: f64, max: f64 },
    /// Lumped R-L-C lines of `len` m, diameter `d`, `nseg` segments per side.
    Lines { len: f64, d: f64, nseg: usize },
    /// Load mass on a spring-damper at the rod end (load side).
    LoadMount { ml: f64, k: f64, d: f64 },
    /// Cylinder body on a compliant mount (piston side): body mass, stiffness, damping.
    BodyMount { mb: f64, k: f64, d: f64 },
    /// Command delay (s).
    Delay { tau: f64 },
    /// Tone a·sin(2πft + φ) on a channel (0 force, 1 position, 2 p_a).
    Tone {
        ch: usize,
        f: f64,
        a: f64,
        phase: f64,
    },
    /// Supply through a resistance from an accumulator: τ·ṗ_s = p₀ − R·Q_s − p_s.
    SupplyResistance { r: f64, tau: f64 },
    /// Pressure-compensated pump with a flow limit into a supply volume:
    /// (V/β)·ṗ_s = Q_max·clamp((p_set − p_s)/Δp_c + 1 − …) − Q_s (see [`pump_flow`]).
    PumpLimit { qmax: f64, band: f64, vol: f64 },
}

impl Hidden {
    /// The same effect at α of its strength, physically (`alpha` in (0, 1]): every force law
    /// and leak coefficient, dead band, delay, air fraction, β slope, tone, supply resistance
    /// and line length × α; a spool limit's reach beyond it (1 − L) × α; a spool's time scale
    /// × α; a mount's stiffness ÷ α at the same damping ratio; a pump's flow limit ÷ α. The
    /// catalogue parameters of these sizes are those `limscore` scales the same way, so that
    /// a detection limit can be checked on a physical effect of known size rather than on a
    /// blend of records (`make_case_small`), which no effect of a smaller size produces for
    /// a mode or a friction with stick-slip.
    pub fn at_strength(&self, alpha: f64) -> Hidden {
        if alpha == 1.0 {
            // Bit for bit the drawn effect (1 − 1·(1 − L) is not L in floating point).
            return self.clone();
        }
        let a = alpha;
        let reach = |l: f64| 1.0 - a * (1.0 - l);
        match self.clone() {
            Hidden::LuGre { fc, fs, vs, s0, s1 } => Hidden::LuGre {
                fc: a * fc,
                fs: a * fs,
                vs,
                s0: a * s0,
                s1: a * s1,
            },
            Hidden::LoadCoulomb { fc, veps } => Hidden::LoadCoulomb { fc: a * fc, veps },
            Hidden::Dahl { fc, s0 } => Hidden::Dahl {
                fc: a * fc,
                s0: a * s0,
            },
            Hidden::Hose { len, d, t, e, r } => Hidden::Hose {
                len: a * len,
                d,
                t,
                e,
                r: a * r,
            },
            Hidden::Overlap { ov, offset } => Hidden::Overlap {
                ov: a * ov,
                offset: a * offset,
            },
            Hidden::AmpDeadzone { d, offset } => Hidden::AmpDeadzone {
                d: a * d,
                offset: a * offset,
            },
            Hidden::SoftSaturation { l } => Hidden::SoftSaturation { l: reach(l) },
            Hidden::AsymSaturation { lp, ln } => Hidden::AsymSaturation {
                lp: reach(lp),
                ln: reach(ln),
            },
            Hidden::Spool1 { tau } => Hidden::Spool1 { tau: a * tau },
            Hidden::Spool2 { wn, z } => Hidden::Spool2 { wn: wn / a, z },
            Hidden::InternalLeak { k } => Hidden::InternalLeak { k: a * k },
            Hidden::ExternalLeakBoth { k } => Hidden::ExternalLeakBoth { k: a * k },
            Hidden::ExternalLeakA { k } => Hidden::ExternalLeakA { k: a * k },
            Hidden::EntrainedAir { alpha0, n } => Hidden::EntrainedAir {
                alpha0: a * alpha0,
                n,
            },
            Hidden::LinearBeta { slope, max } => Hidden::LinearBeta {
                slope: a * slope,
                max,
            },
            Hidden::Lines { len, d, nseg } => Hidden::Lines {
                len: a * len,
                d,
                nseg,
            },
            Hidden::LoadMount { ml, k, d } => Hidden::LoadMount {
                ml,
                k: k / a,
                d: d / a.sqrt(),
            },
            Hidden::BodyMount { mb, k, d } => Hidden::BodyMount {
                mb,
                k: k / a,
                d: d / a.sqrt(),
            },
            Hidden::Delay { tau } => Hidden::Delay { tau: a * tau },
            Hidden::Tone {
                ch,
                f,
                a: amp,
                phase,
            } => Hidden::Tone {
                ch,
                f,
                a: a * amp,
                phase,
            },
            Hidden::SupplyResistance { r, tau } => Hidden::SupplyResistance { r: a * r, tau },
            Hidden::PumpLimit { qmax, band, vol } => Hidden::PumpLimit {
                qmax: qmax / a,
                band,
                vol,
            },
        }
    }
}

/// Flow of a pressure-compensated pump (m³/s): full displacement until the supply pressure
/// comes within `band` of the setting, then linearly destroked to zero at `p_set`.
pub fn pump_flow(qmax: f64, band: f64, p_set: f64, ps: f64) -> f64 {
    qmax * ((p_set - ps) / band).clamp(0.0, 1.0)
}

/// Catalogue id and plant variant name a hidden effect should be diagnosed as.
pub fn expected(h: &Hidden) -> (&'static str, &'static str) {
    match h {
        Hidden::LuGre { .. } | Hidden::Dahl { .. } => ("friction", "lugre"),
        Hidden::LoadCoulomb { .. } => ("friction", "load_coulomb"),
        Hidden::Overlap { .. } => ("valve_deadband", "overlap"),
        Hidden::AmpDeadzone { .. } => ("valve_deadband", "amplifier"),
        Hidden::SoftSaturation { .. } => ("valve_saturation", "symmetric"),
        Hidden::AsymSaturation { .. } => ("valve_saturation", "asymmetric"),
        Hidden::Spool1 { .. } | Hidden::Spool2 { .. } => ("valve_dynamics", "-"),
        Hidden::InternalLeak { .. } => ("internal_leakage", "-"),
        Hidden::ExternalLeakBoth { .. } => ("external_leakage", "equal"),
        Hidden::ExternalLeakA { .. } => ("external_leakage", "per_chamber"),
        Hidden::EntrainedAir { .. } => ("bulk_modulus_pressure", "entrained_air"),
        Hidden::LinearBeta { .. } => ("bulk_modulus_pressure", "linear"),
        Hidden::Lines { .. } => ("line_dynamics", "pipe"),
        Hidden::Hose { .. } => ("line_dynamics", "hose"),
        Hidden::LoadMount { .. } => ("flexible_mount", "load_side"),
        Hidden::BodyMount { .. } => ("flexible_mount", "piston_side"),
        Hidden::Delay { .. } => ("time_delay", "-"),
        Hidden::Tone { .. } => ("sensor_tone", "-"),
        Hidden::SupplyResistance { .. } => ("supply_pressure_drop", "resistance"),
        Hidden::PumpLimit { .. } => ("supply_pressure_drop", "pump_limit"),
    }
}

/// Generator variant names, in the order of `bench/indep_cases.txt`.
pub const KINDS: [&str; 22] = [
    "lugre",
    "load_coulomb",
    "overlap",
    "amp_deadzone",
    "soft_saturation",
    "asym_saturation",
    "spool1",
    "spool2",
    "internal_leak",
    "external_leak_both",
    "external_leak_a",
    "entrained_air",
    "linear_beta",
    "lines",
    "load_mount",
    "body_mount",
    "delay",
    "tone",
    "supply_resistance",
    "pump_limit",
    "dahl",
    "hose",
];

/// Draw the parameters of generator variant `kind` (or `pump_limit`) for `rig`.
pub fn draw(kind: &str, rig: &Rig, g: &mut Pcg) -> Option<Hidden> {
    draw_mechanical(kind, rig, g)
        .or_else(|| draw_valve(kind, g))
        .or_else(|| draw_fluid(kind, rig, g))
        .or_else(|| draw_sensor(kind, g))
}

/// [`draw`] for the variants of friction and mounts; `None` for another `kind`.
fn draw_mechanical(kind: &str, rig: &Rig, g: &mut Pcg) -> Option<Hidden> {
    Some(match kind {
        "lugre" => {
            let fc = g.range(200.0, 500.0);
            let s0 = g.log_range(3e6, 2e7);
            Hidden::LuGre {
                fc,
                fs: fc * g.range(1.15, 1.6),
                vs: g.log_range(0.004, 0.02),
                s0,
                s1: 0.3 * (s0 * rig.m).sqrt(),
            }
        }
        // Pre-sliding range F_C/σ₀ of 20–80 µm (seal pre-sliding displacements of hydraulic
        // cylinders are tens of µm, e.g. Yanada & Sekikawa 2008, Tribology International 41).
        "dahl" => {
            let fc = g.range(200.0, 500.0);
            Hidden::Dahl {
                fc,
                s0: fc / g.log_range(20e-6, 80e-6),
            }
        }
        "load_coulomb" => Hidden::LoadCoulomb {
            fc: g.range(200.0, 500.0),
            veps: g.log_range(0.002, 0.01),
        },
        "load_mount" => {
            let ml = g.range(15.0, 50.0);
            let k = g.log_range(3e6, 1.2e7);
            Hidden::LoadMount {
                ml,
                k,
                d: g.range(0.05, 0.2) * 2.0 * (k * ml).sqrt(),
            }
        }
        "body_mount" => {
            let mb = g.range(20.0, 60.0);
            let k = g.log_range(4e6, 1.5e7);
            Hidden::BodyMount {
                mb,
                k,
                d: g.range(0.05, 0.2) * 2.0 * (k * mb).sqrt(),
            }
        }
        _ => return None,
    })
}

/// [`draw`] for the variants of the valve and the command path; `None` for another `kind`.
fn draw_valve(kind: &str, g: &mut Pcg) -> Option<Hidden> {
    Some(match kind {
        "overlap" => Hidden::Overlap {
            ov: g.range(0.06, 0.12),
            offset: g.range(-0.01, 0.01),
        },
        "amp_deadzone" => Hidden::AmpDeadzone {
            d: g.range(0.04, 0.10),
            offset: g.range(-0.01, 0.01),
        },
        "soft_saturation" => Hidden::SoftSaturation {
            l: g.range(0.4, 0.65),
        },
        "asym_saturation" => {
            let lp = g.range(0.4, 0.65);
            Hidden::AsymSaturation {
                lp,
                ln: (lp + g.range(0.2, 0.4)).min(1.0),
            }
        }
        "spool1" => Hidden::Spool1 {
            tau: g.range(0.004, 0.012),
        },
        "spool2" => Hidden::Spool2 {
            wn: TAU * g.range(15.0, 45.0),
            z: g.range(0.5, 0.9),
        },
        "delay" => Hidden::Delay {
            tau: g.range(0.003, 0.010),
        },
        _ => return None,
    })
}

/// [`draw`] for the variants of the oil, leakages, lines and supply; `None` for another `kind`.
fn draw_fluid(kind: &str, rig: &Rig, g: &mut Pcg) -> Option<Hidden> {
    let kv = rig.q_rated / rig.dp_rated.sqrt();
    // Flow of one edge at full opening and half the supply (m³/s), and its conductance scale.
    let q_half = kv * (0.5 * rig.ps).sqrt();
    let kc = q_half / rig.ps;
    Some(match kind {
        // A 1.5–4 m hose of 8–13 mm bore; wall 2.5–4 mm of an effective (braid + rubber)
        // modulus of 2–6 GPa: β_eff ≈ 0.3–0.8 GPa of a 1.5 GPa oil; fittings 0.5–2·10⁹ Pa·s/m³
        // (0.5–2 bar at 0.1 L/s) on top of the hose's own laminar resistance.
        "hose" => {
            let (len, d) = (g.range(1.5, 4.0), g.range(8e-3, 13e-3));
            let r_hp = 128.0 * rig.nu * rig.rho * len / (PI * d.powi(4));
            Hidden::Hose {
                len,
                d,
                t: g.range(2.5e-3, 4e-3),
                e: g.range(2e9, 6e9),
                r: r_hp + g.range(0.5e9, 2e9),
            }
        }
        // Leakage conductances ≈ 2–8e-12 m³/(s·Pa): at half supply 15–60 % of an edge's
        // full flow, enough to show on every channel.
        "internal_leak" => Hidden::InternalLeak {
            k: g.log_range(0.15, 0.6) * kc,
        },
        "external_leak_both" => Hidden::ExternalLeakBoth {
            k: g.log_range(0.15, 0.6) * kc,
        },
        "external_leak_a" => Hidden::ExternalLeakA {
            k: g.log_range(0.2, 0.8) * kc,
        },
        "entrained_air" => Hidden::EntrainedAir {
            alpha0: g.log_range(0.004, 0.02),
            n: 1.4,
        },
        "linear_beta" => Hidden::LinearBeta {
            slope: g.range(60.0, 150.0),
            max: 2.4e9,
        },
        "lines" => Hidden::Lines {
            len: g.range(1.5, 4.0),
            d: g.range(6e-3, 10e-3),
            nseg: 4,
        },
        "supply_resistance" => Hidden::SupplyResistance {
            r: g.range(0.15, 0.35) * rig.ps / q_half,
            tau: g.log_range(0.01, 0.05),
        },
        "pump_limit" => Hidden::PumpLimit {
            qmax: g.range(0.8, 1.2) * q_half,
            band: g.range(0.5e6, 1.5e6),
            vol: g.log_range(2e-4, 1e-3),
        },
        _ => return None,
    })
}

/// [`draw`] for the variants of the sensors; `None` for another `kind`.
fn draw_sensor(kind: &str, g: &mut Pcg) -> Option<Hidden> {
    Some(match kind {
        "tone" => {
            let ch = (g.u() * 3.0) as usize;
            let a = match ch {
                0 => g.range(25.0, 50.0),
                1 => g.range(2e-5, 5e-5),
                _ => g.range(1e5, 2e5),
            };
            Hidden::Tone {
                ch,
                f: g.range(60.0, 300.0),
                a,
                phase: g.range(0.0, TAU),
            }
        }
        _ => return None,
    })
}

/// Cavitation floor of every pressure (Pa gauge): ≈ 5 kPa absolute, the vapour pressure
/// region of mineral oil.
pub const P_CAV: f64 = -0.95e5;

/// Right-hand side, state layout and outputs of the generator's rig with one hidden effect.
struct Model<'a> {
    r: &'a Rig,
    /// The hidden effects (at most one per site of the model: see [`make_case`]).
    hs: &'a [Hidden],
    kv: f64,
    /// Index of extra states.
    i_spool: usize,
    i_z: usize,
    i_ps: usize,
    i_mount: usize,
    i_line: usize,
    /// Hose volume pressures A, B (variant `Hose`).
    i_hose: usize,
    n: usize,
    /// Line constants per segment (R, L, C).
    line: (f64, f64, f64, usize),
}

impl<'a> Model<'a> {
    fn new(r: &'a Rig, hs: &'a [Hidden]) -> Self {
        let find = |f: fn(&Hidden) -> bool| hs.iter().find(|h| f(h));
        let mut n = 4; // x, v, p_a, p_b
        let mut take = |k: usize| {
            let i = n;
            n += k;
            i
        };
        let i_spool = match find(|h| matches!(h, Hidden::Spool1 { .. } | Hidden::Spool2 { .. })) {
            Some(Hidden::Spool1 { .. }) => take(1),
            Some(Hidden::Spool2 { .. }) => take(2),
            _ => usize::MAX,
        };
        let i_z = match find(|h| matches!(h, Hidden::LuGre { .. } | Hidden::Dahl { .. })) {
            Some(Hidden::LuGre { .. }) | Some(Hidden::Dahl { .. }) => take(1),
            _ => usize::MAX,
        };
        let i_ps = match find(|h| {
            matches!(
                h,
                Hidden::SupplyResistance { .. } | Hidden::PumpLimit { .. }
            )
        }) {
            Some(Hidden::SupplyResistance { .. }) | Some(Hidden::PumpLimit { .. }) => take(1),
            _ => usize::MAX,
        };
        let i_mount =
            match find(|h| matches!(h, Hidden::LoadMount { .. } | Hidden::BodyMount { .. })) {
                Some(Hidden::LoadMount { .. }) | Some(Hidden::BodyMount { .. }) => take(2),
                _ => usize::MAX,
            };
        let i_hose = match find(|h| matches!(h, Hidden::Hose { .. })) {
            Some(Hidden::Hose { .. }) => take(2),
            _ => usize::MAX,
        };
        let mut line = (0.0, 0.0, 0.0, 0);
        let i_line = match find(|h| matches!(h, Hidden::Lines { .. })) {
            Some(Hidden::Lines { len, d, nseg }) => {
                let a = PI / 4.0 * d * d;
                let ls = len / *nseg as f64;
                let mu = r.nu * r.rho;
                // Hagen–Poiseuille resistance, plug-flow inertance, fluid capacitance.
                line = (
                    128.0 * mu * ls / (PI * d.powi(4)),
                    r.rho * ls / a,
                    a * ls / r.beta,
                    *nseg,
                );
                // Per side: nseg node pressures (node 0 at the valve) and nseg flows.
                take(4 * nseg)
            }
            _ => usize::MAX,
        };
        Model {
            r,
            hs,
            kv: r.q_rated / r.dp_rated.sqrt(),
            i_spool,
            i_z,
            i_ps,
            i_mount,
            i_line,
            i_hose,
            n,
            line,
        }
    }

    /// The hidden effect among `hs` that `f` selects (the site's kinds), if any.
    fn find(&self, f: impl Fn(&Hidden) -> bool) -> Option<&'a Hidden> {
        self.hs.iter().find(|h| f(h))
    }

    /// Bulk modulus at gauge pressure p (Pa).
    fn beta(&self, p: f64) -> f64 {
        match self.find(|h| matches!(h, Hidden::EntrainedAir { .. } | Hidden::LinearBeta { .. })) {
            Some(Hidden::EntrainedAir { alpha0, n }) => {
                // Yu et al. (1994) / Gholizadeh et al. (2011) eq. for an air–oil mixture with
                // the air compressed polytropically from atmospheric p₀ (absolute pressures):
                // β = [(1−α₀) + α₀(p₀/p)^(1/n)] / [(1−α₀)/β_l + α₀(p₀/p)^(1/n)/(n·p)].
                let p0 = 101_325.0;
                let pa = (p + p0).max(0.2 * p0);
                let air = alpha0 * (p0 / pa).powf(1.0 / n);
                ((1.0 - alpha0) + air) / ((1.0 - alpha0) / self.r.beta + air / (n * pa))
            }
            Some(Hidden::LinearBeta { slope, max }) => {
                (self.r.beta + slope * p.max(0.0)).min(max.max(self.r.beta))
            }
            _ => self.r.beta,
        }
    }

    /// Signed edge law sign(Δp)·√|Δp| with a linear core below `dp_lam`.
    fn root(&self, dp: f64) -> f64 {
        let l = self.r.dp_lam;
        if dp.abs() >= l {
            dp.signum() * dp.abs().sqrt()
        } else {
            dp / l.sqrt()
        }
    }

    /// Spool position from the command (before spool dynamics) and the state.
    fn spool_target(&self, u: f64) -> f64 {
        let c = u / self.r.full_scale;
        match self.find(|h| matches!(h, Hidden::AmpDeadzone { .. })) {
            Some(Hidden::AmpDeadzone { d, offset }) => {
                let c = c + offset;
                c.signum() * (c.abs() - d).max(0.0)
            }
            _ => c,
        }
        .clamp(-1.0, 1.0)
    }

    /// Valve flows into ports A and B and from supply (m³/s) at spool `s`.
    fn valve(&self, s: f64, ps: f64, pa: f64, pb: f64) -> (f64, f64, f64) {
        let (mut s, mut lap) = (s, self.r.underlap);
        match self.find(|h| {
            matches!(
                h,
                Hidden::Overlap { .. }
                    | Hidden::SoftSaturation { .. }
                    | Hidden::AsymSaturation { .. }
            )
        }) {
            Some(Hidden::Overlap { ov, offset }) => {
                s -= offset;
                lap -= ov;
            }
            Some(Hidden::SoftSaturation { l }) => s = l * (s / l).tanh(),
            Some(Hidden::AsymSaturation { lp, ln }) => s = s.clamp(-ln, *lp),
            _ => {}
        }
        let pos = (s + lap).max(0.0);
        let neg = (-s + lap).max(0.0);
        let k = self.kv;
        let q_pa = k * pos * self.root(ps - pa);
        let q_at = k * neg * self.root(pa);
        let q_pb = k * neg * self.root(ps - pb);
        let q_bt = k * pos * self.root(pb);
        (q_pa - q_at, q_pb - q_bt, q_pa + q_pb)
    }

    fn friction(&self, y: &[f64], v: f64) -> (f64, f64) {
        match self.find(|h| {
            matches!(
                h,
                Hidden::LuGre { .. } | Hidden::Dahl { .. } | Hidden::LoadCoulomb { .. }
            )
        }) {
            Some(Hidden::LuGre { fc, fs, vs, s0, s1 }) => {
                let z = y[self.i_z];
                let g = fc + (fs - fc) * (-(v / vs).powi(2)).exp();
                let zd = v - s0 * v.abs() * z / g;
                (s0 * z + s1 * zd, zd)
            }
            Some(Hidden::LoadCoulomb { fc, veps }) => (fc * 2.0 / PI * (v / veps).atan(), 0.0),
            Some(Hidden::Dahl { fc, s0 }) => {
                let f = y[self.i_z];
                (f, s0 * (v - v.abs() * f / fc))
            }
            _ => (0.0, 0.0),
        }
    }

    /// dy/dt at command `u` (V, already delayed): the spool, the valve's flows at the supply
    /// pressure, the supply, the lines or hoses to the chambers, the chamber pressures, the
    /// mechanics.
    fn rhs(&self, y: &[f64], u: f64, dy: &mut [f64]) {
        let (pa, pb) = (y[2], y[3]);
        let s = self.spool(y, u, dy);
        let ps = if self.i_ps != usize::MAX {
            y[self.i_ps]
        } else {
            self.r.ps
        };
        // Valve ports: the chambers, or the valve-side line nodes.
        let (port_a, port_b) = if self.i_line != usize::MAX {
            let ns = self.line.3;
            (y[self.i_line], y[self.i_line + 2 * ns])
        } else if self.i_hose != usize::MAX {
            (y[self.i_hose], y[self.i_hose + 1])
        } else {
            (pa, pb)
        };
        let (qa, qb, qs) = self.valve(s, ps, port_a, port_b);
        if self.i_ps != usize::MAX {
            dy[self.i_ps] = self.supply_rate(ps, qs);
        }
        let into = self.inflows(y, (qa, qb), dy);
        self.chambers(y, into, dy);
        self.mechanics(y, dy);
    }

    /// The spool's position (its state, or the target of an ideal spool) and its states'
    /// derivatives in `dy`, at command `u` (V).
    fn spool(&self, y: &[f64], u: f64, dy: &mut [f64]) -> f64 {
        let target = self.spool_target(u);
        match self.find(|h| matches!(h, Hidden::Spool1 { .. } | Hidden::Spool2 { .. })) {
            Some(Hidden::Spool1 { tau }) => {
                dy[self.i_spool] = (target - y[self.i_spool]) / tau;
                y[self.i_spool]
            }
            Some(Hidden::Spool2 { wn, z }) => {
                let (s, sd) = (y[self.i_spool], y[self.i_spool + 1]);
                dy[self.i_spool] = sd;
                dy[self.i_spool + 1] = wn * wn * (target - s) - 2.0 * z * wn * sd;
                s
            }
            _ => target,
        }
    }

    /// dp_s/dt (Pa/s) of a supply with a resistance or a pump limit at pressure `ps` (Pa)
    /// and the valve's supply flow `qs` (m³/s).
    fn supply_rate(&self, ps: f64, qs: f64) -> f64 {
        let r = self.r;
        match self.find(|h| {
            matches!(
                h,
                Hidden::SupplyResistance { .. } | Hidden::PumpLimit { .. }
            )
        }) {
            Some(Hidden::SupplyResistance { r: rs, tau }) => (r.ps - rs * qs - ps) / tau,
            Some(Hidden::PumpLimit { qmax, band, vol }) => {
                r.beta / vol * (pump_flow(*qmax, *band, r.ps, ps) - qs)
            }
            _ => 0.0,
        }
    }

    /// The flows reaching the chambers (m³/s) from the valve's port flows `q`: through the
    /// line segments or the hoses (their states' derivatives in `dy`), or directly.
    fn inflows(&self, y: &[f64], (qa, qb): (f64, f64), dy: &mut [f64]) -> (f64, f64) {
        let (pa, pb) = (y[2], y[3]);
        if self.i_line != usize::MAX {
            let (rl, ll, cl, ns) = self.line;
            let mut ends = [0.0; 2];
            for (side, (q_valve, p_ch)) in [(qa, pa), (qb, pb)].into_iter().enumerate() {
                let ip = self.i_line + 2 * ns * side;
                let iq = ip + ns;
                for j in 0..ns {
                    // Node j: half a segment's capacitance at the valve end, full inside.
                    let cap = if j == 0 { 0.5 * cl } else { cl };
                    let q_in = if j == 0 { q_valve } else { y[iq + j - 1] };
                    dy[ip + j] = (q_in - y[iq + j]) / cap;
                    if y[ip + j] <= P_CAV && dy[ip + j] < 0.0 {
                        dy[ip + j] = 0.0;
                    }
                    let p_next = if j + 1 < ns { y[ip + j + 1] } else { p_ch };
                    dy[iq + j] = (y[ip + j] - p_next - rl * y[iq + j]) / ll;
                }
                ends[side] = y[iq + ns - 1];
            }
            (ends[0], ends[1])
        } else if let Some(Hidden::Hose {
            len,
            d,
            t,
            e,
            r: rh,
        }) = self.find(|h| matches!(h, Hidden::Hose { .. }))
        {
            // Each hose a lumped volume at the valve port, laminar resistance to the chamber.
            let vol = PI / 4.0 * d * d * len;
            let mut into = [0.0; 2];
            for (side, (q_valve, p_ch)) in [(qa, pa), (qb, pb)].into_iter().enumerate() {
                let i = self.i_hose + side;
                let ph = y[i];
                let beta_eff = 1.0 / (1.0 / self.beta(ph) + d / (t * e));
                into[side] = (ph - p_ch) / rh;
                dy[i] = beta_eff / vol * (q_valve - into[side]);
                if ph <= P_CAV && dy[i] < 0.0 {
                    dy[i] = 0.0;
                }
            }
            (into[0], into[1])
        } else {
            (qa, qb)
        }
    }

    /// dp/dt of the chambers (Pa/s) with the flows `into` them (m³/s), the leakages and the
    /// piston's displacement; held at the cavitation floor.
    fn chambers(&self, y: &[f64], (into_a, into_b): (f64, f64), dy: &mut [f64]) {
        let r = self.r;
        let (x, v, pa, pb) = (y[0], y[1], y[2], y[3]);
        let (k_in, k_ea, k_eb) = match self.find(|h| {
            matches!(
                h,
                Hidden::InternalLeak { .. }
                    | Hidden::ExternalLeakBoth { .. }
                    | Hidden::ExternalLeakA { .. }
            )
        }) {
            Some(Hidden::InternalLeak { k }) => (*k, 0.0, 0.0),
            Some(Hidden::ExternalLeakBoth { k }) => (0.0, *k, *k),
            Some(Hidden::ExternalLeakA { k }) => (0.0, *k, 0.0),
            _ => (0.0, 0.0, 0.0),
        };
        let xc = x.clamp(0.0, r.stroke);
        let (va, vb) = (r.va0 + r.aa * xc, r.vb0 + r.ab * (r.stroke - xc));
        // With line dynamics the last half segment's oil is added to the chamber.
        let extra = if self.i_line != usize::MAX {
            0.5 * self.line.2 * r.beta
        } else {
            0.0
        };
        let q_in = k_in * (pa - pb);
        dy[2] = self.beta(pa) / (va + extra) * (into_a - r.aa * v - q_in - k_ea * pa);
        dy[3] = self.beta(pb) / (vb + extra) * (into_b + r.ab * v + q_in - k_eb * pb);
        // Cavitation: the oil releases vapour and air instead of going below P_CAV (a
        // one-sided floor on every pressure state; the state is clamped after each step).
        for (i, pi) in [(2, pa), (3, pb)] {
            if pi <= P_CAV && dy[i] < 0.0 {
                dy[i] = 0.0;
            }
        }
    }

    /// The piston's (and a mount's) acceleration, the friction state's rate.
    fn mechanics(&self, y: &[f64], dy: &mut [f64]) {
        let r = self.r;
        let (x, v, pa, pb) = (y[0], y[1], y[2], y[3]);
        let f_h = pa * r.aa - pb * r.ab;
        let (f_fr, zd) = self.friction(y, v);
        if self.i_z != usize::MAX {
            dy[self.i_z] = zd;
        }
        dy[0] = v;
        match self.find(|h| matches!(h, Hidden::LoadMount { .. } | Hidden::BodyMount { .. })) {
            Some(Hidden::LoadMount { ml, k, d }) => {
                let (xl, vl) = (y[self.i_mount], y[self.i_mount + 1]);
                let f_m = k * (x - xl) + d * (v - vl);
                dy[1] = (f_h - r.c * v - r.k * (x - 0.5 * r.stroke) - f_fr - f_m) / r.m;
                dy[self.i_mount] = vl;
                dy[self.i_mount + 1] = f_m / ml;
            }
            Some(Hidden::BodyMount { mb, k, d }) => {
                // x, v relative to the body; the body (xb, vb) takes the reaction of the
                // hydraulic, viscous and seal forces; the centring spring is grounded.
                let (xb, vb) = (y[self.i_mount], y[self.i_mount + 1]);
                let f_rel = f_h - r.c * v - f_fr;
                let ab_ = (-f_rel - k * xb - d * vb) / mb;
                let a_abs = (f_rel - r.k * (x + xb - 0.5 * r.stroke)) / r.m;
                dy[1] = a_abs - ab_;
                dy[self.i_mount] = vb;
                dy[self.i_mount + 1] = ab_;
            }
            _ => {
                dy[1] = (f_h - r.c * v - r.k * (x - 0.5 * r.stroke) - f_fr) / r.m;
            }
        }
    }

    /// Rod force seen by the load cell (N).
    fn rod_force(&self, y: &[f64]) -> f64 {
        let r = self.r;
        match self.find(|h| matches!(h, Hidden::LoadMount { .. } | Hidden::BodyMount { .. })) {
            Some(Hidden::LoadMount { k, d, .. }) => {
                r.k * (y[0] - 0.5 * r.stroke)
                    + k * (y[0] - y[self.i_mount])
                    + d * (y[1] - y[self.i_mount + 1])
            }
            Some(Hidden::BodyMount { .. }) => r.k * (y[0] + y[self.i_mount] - 0.5 * r.stroke),
            _ => r.k * (y[0] - 0.5 * r.stroke),
        }
    }
}

/// Excitation (V): a multisine of 12 log-spaced lines (0.7–35 Hz, random phases, 2.5 V peak)
/// on random levels (±8 V, held 80–250 ms).
pub fn command(g: &mut Pcg, dt: f64, n: usize) -> Vec<f64> {
    let lines: Vec<(f64, f64)> = (0..12)
        .map(|i| {
            let f = 0.7 * (35.0f64 / 0.7).powf(i as f64 / 11.0);
            (f, g.range(0.0, TAU))
        })
        .collect();
    let mut level = 0.0;
    let mut next = 0.04;
    (0..n)
        .map(|k| {
            let t = k as f64 * dt;
            if t >= next {
                level = g.range(-8.0, 8.0);
                next = t + g.range(0.08, 0.25);
            }
            let ms: f64 = lines.iter().map(|(f, ph)| (TAU * f * t + ph).sin()).sum();
            if t < 0.04 {
                0.0
            } else {
                (level + 2.5 / 12f64.sqrt() * ms).clamp(-10.0, 10.0)
            }
        })
        .collect()
}

/// A generated case.
#[derive(Debug, Clone)]
pub struct Case {
    /// Seed.
    pub seed: u64,
    /// Generator variant name (`clean` for none).
    pub kind: String,
    /// The hidden effect (the first of a pair).
    pub hidden: Option<Hidden>,
    /// Further hidden effects of a case with two or three at once (`a+b` kinds).
    pub more: Vec<Hidden>,
    /// Nominal config for the diagnosis (no effect, ±10 % parameter errors).
    pub nominal: PlantParams,
    /// The record.
    pub record: Record,
    /// How the diagnosis must replay it: the recorded command, or for a `pi_` case the
    /// rig's PI force loop on the recorded force setpoint `ref` (the gains the rig ran with).
    pub drive: ehactl_ident::replay::Drive,
}

impl Case {
    /// Every hidden effect, first to last.
    pub fn all_hidden(&self) -> Vec<&Hidden> {
        self.hidden.iter().chain(&self.more).collect()
    }
}

/// The part of the generator's model a hidden effect changes; two effects of one case must
/// change different parts (the model holds one effect per part).
pub fn site(h: &Hidden) -> &'static str {
    match h {
        Hidden::LuGre { .. } | Hidden::Dahl { .. } | Hidden::LoadCoulomb { .. } => "friction",
        Hidden::Overlap { .. } | Hidden::SoftSaturation { .. } | Hidden::AsymSaturation { .. } => {
            "valve"
        }
        Hidden::AmpDeadzone { .. } => "amplifier",
        Hidden::Spool1 { .. } | Hidden::Spool2 { .. } => "spool",
        Hidden::InternalLeak { .. }
        | Hidden::ExternalLeakBoth { .. }
        | Hidden::ExternalLeakA { .. } => "leakage",
        Hidden::EntrainedAir { .. } | Hidden::LinearBeta { .. } => "bulk modulus",
        Hidden::Lines { .. } | Hidden::Hose { .. } => "lines",
        Hidden::LoadMount { .. } | Hidden::BodyMount { .. } => "mount",
        Hidden::Delay { .. } => "delay",
        Hidden::Tone { .. } => "tone",
        Hidden::SupplyResistance { .. } | Hidden::PumpLimit { .. } => "supply",
    }
}

/// The force rig of the `pi_` cases: the generator's rig pressing on a stiff load (a load
/// cell and frame of 2e7 N/m, relaxed at mid stroke) through a nearly critically lapped valve
/// (underlap 0.5 % of travel), under PI force control ([`force_pi_gains`]). From the valve
/// command the force is then close to an integrator (the valve's flow integrated by the load
/// stiffness, little pressure feedback from a tight centre), the case where an open-loop
/// replay from `u` drifts. Assumed values of a plausible force bench, not a paper's rig.
pub fn force_rig() -> Rig {
    Rig {
        k: 2.0e7,
        underlap: 0.005,
        ..Rig::default()
    }
}

/// PI force controller of the `pi_` cases, on load-cell volts at 1 mV/N. Tuned on the
/// quasi-static loop of [`force_rig`]: force rate ≈ k_eff·K_v·u with k_eff ≈ 1.4e7 N/m (load
/// stiffness in series with the oil's) and K_v ≈ 0.0135 m/s per V, so K_P = 0.34 V/V would put
/// the crossover near 10 Hz, well below the rig's 190 Hz mode; K_P = 0.2 V/V (crossover near
/// 6 Hz) is used because ±10 % parameter errors made the replay of the 0.34 loop oscillate
/// (chosen by trial, not derived); I = 20 1/s puts the PI zero at 3 Hz. Clamping anti-windup at ±10 V (the valve's full scale).
pub fn force_pi_gains() -> ehactl_control::pi::PiGains {
    ehactl_control::pi::PiGains {
        kp: 0.2,
        integral: 20.0,
        error_scale: 1e-3,
        u_min: -10.0,
        u_max: 10.0,
        tracking: 0.0,
        feedforward: 0.0,
    }
}

/// Force setpoint scale of the `pi_` cases (N per V of [`command`]'s excitation): levels up to
/// ±4.8 kN, the multisine ≈ ±1.5 kN on top, within the 17.6 kN the supply pushes on A.
pub const FORCE_REF_SCALE: f64 = 600.0;

/// Nominal plant config of `rig` with nominal errors (factors) on valve flow, β, damping,
/// mass and spring rate, as the TOML a user would write.
pub fn nominal_config(rig: &Rig, f: [f64; 5], dt: f64) -> PlantParams {
    let toml = format!(
        r#"
[fluid]
density = {rho:e}
bulk_modulus = {beta:e}
kinematic_viscosity = {nu:e}
[supply]
pressure = {ps:e}
tank_pressure = 0.0
[valve]
command_full_scale = {fs:e}
flow_form = "kq"
rated_flow = {q:e}
rated_pressure_drop = {dpr:e}
underlap = {ul:e}
laminar_pressure = {lam:e}
[cylinder]
area_a = {aa:e}
area_b = {ab:e}
dead_volume_a = {va:e}
dead_volume_b = {vb:e}
stroke = {st:e}
initial_position = {x0:e}
[mechanics]
mass = {m:e}
damping = {c:e}
load_stiffness = {k:e}
load_contact_position = {x0:e}
end_stops = true
[sensors.force]
noise = {nf:e}
[sensors.position]
noise = {nx:e}
[sensors.pressure]
noise = {np:e}
"#,
        rho = rig.rho,
        beta = rig.beta * f[1],
        nu = rig.nu,
        ps = rig.ps,
        fs = rig.full_scale,
        q = rig.q_rated * f[0],
        dpr = rig.dp_rated,
        ul = rig.underlap,
        lam = rig.dp_lam,
        aa = rig.aa,
        ab = rig.ab,
        va = rig.va0,
        vb = rig.vb0,
        st = rig.stroke,
        x0 = 0.5 * rig.stroke,
        m = rig.m * f[3],
        c = rig.c * f[2],
        k = rig.k * f[4],
        nf = rig.noise.0,
        nx = rig.noise.1,
        np = rig.noise.2,
    );
    let _ = dt;
    toml::from_str(&toml).expect("generator nominal config is a valid plant config")
}

/// Generate case `seed` with generator variant `kind` (`clean` for none): `duration` s at
/// sample period `dt`, RK4 with `dt/substeps` steps, 0.3 s of settling at zero command first.
///
/// `kind` may name two or three effects at once (`a+b`, drawn in that order; each must change
/// a different part of the model, [`site`]), and may start with `pi_` (`pi_clean`,
/// `pi_internal_leak+delay`): the [`force_rig`] under closed-loop PI force control
/// ([`force_pi_gains`], the same `ehactl_control::pi::Pi` an ehactl-controlled rig runs, acting
/// on the noisy measured force) tracking a force setpoint of [`FORCE_REF_SCALE`] × the
/// excitation; the record then has the setpoint as `ref` and the controller's output as `u`.
///
/// A kind ending in `@L` (`lines@3`, `pi_delay@2.5`) is the same case with its effects at a
/// small magnitude: the residual of the channel they move most at L × its sensor noise
/// ([`make_case_small`]).
pub fn make_case(seed: u64, kind: &str, duration: f64, dt: f64) -> Result<Case, String> {
    made(seed, kind, duration, dt, make_case_small)
}

/// [`make_case`] with a small case (`kind@L`) made physical ([`make_case_small_physical`]).
pub fn make_case_physical(seed: u64, kind: &str, duration: f64, dt: f64) -> Result<Case, String> {
    made(seed, kind, duration, dt, make_case_small_physical)
}

/// The case `kind` of `seed`, a small one (`kind@L`) by `small(seed, base, L, duration, dt)`.
fn made(
    seed: u64,
    kind: &str,
    duration: f64,
    dt: f64,
    small: fn(u64, &str, f64, f64, f64) -> Result<Case, String>,
) -> Result<Case, String> {
    if let Some((base, level)) = kind.split_once('@') {
        let level: f64 = level
            .parse()
            .map_err(|_| format!("`{kind}`: the level after `@` is not a number"))?;
        let mut c = small(seed, base, level, duration, dt)?;
        c.kind = kind.to_string();
        return Ok(c);
    }
    generate(seed, kind, duration, dt, &|_| true)
}

/// The record of case `kind` of `seed` with hidden effect number `drop` (0-based, in the
/// order of `kind`) switched off and every draw, the excitation and the sensor noise kept:
/// the truth against which the error each effect of a multi-effect case explains is measured
/// (the record with all effects minus this one).
pub fn make_case_without(
    seed: u64,
    kind: &str,
    drop: usize,
    duration: f64,
    dt: f64,
) -> Result<Case, String> {
    generate(seed, kind, duration, dt, &|i| i != drop)
}

/// The case `kind` of `seed` with its hidden effects at a small magnitude: the clean record
/// (the same draws, excitation, nominal errors and sensor noise, the effects switched off)
/// plus α × (the record with the effects − the clean record), α putting the channel the
/// effects move most at `level` × its sensor noise ([`crate::synth::small_effect`]; to first
/// order the effects at α × their size, their signature kept). A closed-loop (`pi_`) case
/// blends the PI's command the same way.
pub fn make_case_small(
    seed: u64,
    kind: &str,
    level: f64,
    duration: f64,
    dt: f64,
) -> Result<Case, String> {
    blend(seed, kind, level, duration, dt).map(|(c, _)| c)
}

/// [`make_case_small`] and its α.
fn blend(seed: u64, kind: &str, level: f64, duration: f64, dt: f64) -> Result<(Case, f64), String> {
    let full = generate(seed, kind, duration, dt, &|_| true)?;
    let clean = generate(seed, kind, duration, dt, &|_| false)?;
    let rig = if kind.starts_with("pi_") {
        force_rig()
    } else {
        Rig::default()
    };
    let noise = |k: ChannelKind| match k {
        ChannelKind::Force => rig.noise.0,
        ChannelKind::Position => rig.noise.1,
        _ => rig.noise.2,
    };
    let (mut record, alpha) = crate::synth::small_effect(&clean.record, &full.record, level, noise)
        .ok_or_else(|| format!("seed {seed} {kind}: no effect to scale"))?;
    record.source = format!(
        "independent generator seed {seed} ({kind} at {level}× the noise, α = {alpha:.3e})"
    );
    Ok((Case { record, ..full }, alpha))
}

/// The small case `kind@level` of `seed` made physical: its hidden effects at the α that
/// [`make_case_small`] finds for the blend ([`Hidden::at_strength`]), the same draws
/// otherwise. The record's source states α as the blend's does, and `hidden` keeps the
/// full-size effects, so that the blend's scoring (`limscore::small_size`) gives the
/// physical size.
pub fn make_case_small_physical(
    seed: u64,
    kind: &str,
    level: f64,
    duration: f64,
    dt: f64,
) -> Result<Case, String> {
    let (blend, alpha) = blend(seed, kind, level, duration, dt)?;
    let mut c = make_case_at_strength(seed, kind, alpha, duration, dt)?;
    c.record.source = format!(
        "independent generator seed {seed} ({kind}, its effects physically at α = {alpha:.3e})"
    );
    c.hidden = blend.hidden;
    c.more = blend.more;
    Ok(c)
}

/// The case `kind` of `seed` with its hidden effects physically at `strength` of their
/// drawn size ([`Hidden::at_strength`]), the same draws otherwise.
pub fn make_case_at_strength(
    seed: u64,
    kind: &str,
    strength: f64,
    duration: f64,
    dt: f64,
) -> Result<Case, String> {
    generate_with(seed, kind, duration, dt, &|_| true, None, strength)
}

/// The case `kind` of `seed` (the same draws as [`make_case`]: hidden effects, nominal
/// errors) driven by the excitation `excitation` instead of its own (the valve command in V
/// open loop, the force setpoint in N for a `pi_` case), sampled at `dt` (s): how a proposed
/// next test (`ehactl_ident::nexttest`) is played on this generator.
pub fn make_case_driven(
    seed: u64,
    kind: &str,
    excitation: &[f64],
    dt: f64,
) -> Result<Case, String> {
    let duration = excitation.len() as f64 * dt;
    generate_with(seed, kind, duration, dt, &|_| true, Some(excitation), 1.0)
}

/// The small-magnitude case `kind` of `seed` at the fraction `alpha` of its effects (as
/// [`make_case_small`] made it, whose record's source states α) driven by `excitation`
/// ([`make_case_driven`]): the clean record of the same draws plus α × (the record with the
/// effects − the clean record), both driven by `excitation`: the same small effect under
/// another test.
pub fn make_case_small_driven(
    seed: u64,
    kind: &str,
    alpha: f64,
    excitation: &[f64],
    dt: f64,
) -> Result<Case, String> {
    let duration = excitation.len() as f64 * dt;
    let full = generate_with(seed, kind, duration, dt, &|_| true, Some(excitation), 1.0)?;
    let clean = generate_with(seed, kind, duration, dt, &|_| false, Some(excitation), 1.0)?;
    let mut record = clean.record.clone();
    for (c, f) in record.channels.iter_mut().zip(&full.record.channels) {
        for (y, yf) in c.values.iter_mut().zip(&f.values) {
            *y += alpha * (yf - *y);
        }
    }
    for (u, uf) in record.u.iter_mut().zip(&full.record.u) {
        *u += alpha * (uf - *u);
    }
    record.source = format!("independent generator seed {seed} ({kind}, α = {alpha:.3e}, driven)");
    Ok(Case { record, ..full })
}

/// [`make_case`] without the `@L` suffix, simulating the hidden effects `keep` selects (by
/// index in `kind`); the others are drawn and listed but not simulated (`|_| false`: the clean
/// record of the same draws).
fn generate(
    seed: u64,
    kind: &str,
    duration: f64,
    dt: f64,
    keep: &dyn Fn(usize) -> bool,
) -> Result<Case, String> {
    generate_with(seed, kind, duration, dt, keep, None, 1.0)
}

/// [`generate`] with the excitation `given` in place of the drawn one (drawn all the same,
/// so that the sensor noise keeps its draws). The steps, in the order they draw from the
/// seed's generator: the hidden effects, the nominal parameters' errors, the excitation;
/// the model of the effects `keep` selects, settled at zero command; then per sample the
/// measured channels with their noise, the PI's command on a closed loop, and the RK4
/// substeps.
fn generate_with(
    seed: u64,
    kind: &str,
    duration: f64,
    dt: f64,
    keep: &dyn Fn(usize) -> bool,
    given: Option<&[f64]>,
    strength: f64,
) -> Result<Case, String> {
    let (closed, effects) = match kind.strip_prefix("pi_") {
        Some(rest) => (true, rest),
        None => (false, kind),
    };
    let rig = if closed { force_rig() } else { Rig::default() };
    let mut g = Pcg::new(seed);
    let all = draw_all(kind, effects, &rig, &mut g)?;
    let f = [0; 5].map(|_| g.range(0.9, 1.1));
    let nominal = nominal_config(&rig, f, dt);
    let n = (duration / dt).round() as usize;
    let drawn = command(&mut g, dt, n);
    let excitation = given.map_or(drawn, |e| e[..n.min(e.len())].to_vec());
    let n = excitation.len();
    // Open loop: the excitation is the valve command. Closed loop: it is the force setpoint
    // and the command is the PI's output, filled in sample by sample below.
    let (mut u, reference) = if closed {
        let r: Vec<f64> = excitation.iter().map(|e| FORCE_REF_SCALE * e).collect();
        (Vec::with_capacity(n), Some(r))
    } else {
        (excitation, None)
    };
    let mut pi = ehactl_control::pi::Pi::new(force_pi_gains());
    let sim: Vec<Hidden> = all
        .iter()
        .enumerate()
        .filter(|(i, _)| keep(*i))
        .map(|(_, h)| h.at_strength(strength))
        .collect();
    let sim = &sim[..];
    let model = Model::new(&rig, sim);
    let mut y = initial_state(&model, &rig, sim);
    let substeps = 20;
    let h = dt / substeps as f64;
    let delay = sim
        .iter()
        .find_map(|h| match h {
            Hidden::Delay { tau } => Some(*tau),
            _ => None,
        })
        .unwrap_or(0.0);
    let mut rk = Rk4::new(model.n, h);
    let settle = (0.3 / h).round() as usize;
    for _ in 0..settle {
        rk.step(&model, &mut y, 0.0);
    }
    let tone = Tone::of(sim);
    let mut cols: Vec<Vec<f64>> = (0..4).map(|_| Vec::with_capacity(n)).collect();
    let mut t = Vec::with_capacity(n);
    for kk in 0..n {
        let tk = kk as f64 * dt;
        check_state(&y, rig.stroke, tk).map_err(|e| format!("seed {seed} {kind}: {e}"))?;
        t.push(tk);
        cols[0].push(model.rod_force(&y) + rig.noise.0 * g.normal() + tone.at(0, tk));
        cols[1].push(y[0] + rig.noise.1 * g.normal() + tone.at(1, tk));
        cols[2].push(y[2] + rig.noise.2 * g.normal() + tone.at(2, tk));
        cols[3].push(y[3] + rig.noise.2 * g.normal());
        if let Some(r) = &reference {
            // Read, compute, write (the order of `ehactl run`): the PI acts on this sample's
            // measured force.
            let force = cols[0][kk];
            u.push(pi.step(r[kk], force, dt).u);
        }
        for sub in 0..substeps {
            let ts = tk + sub as f64 * h;
            // Zero-order hold on the sample grid, delayed by `delay`.
            let td = ts - delay + 1e-12;
            let uc = if td < 0.0 {
                0.0
            } else {
                u[((td / dt).floor() as usize).min(n - 1)]
            };
            rk.step(&model, &mut y, uc);
        }
    }
    let record = record_of(
        &format!("independent generator seed {seed} ({kind})"),
        t,
        u,
        cols,
        reference,
    )?;
    Ok(Case {
        seed,
        kind: kind.to_string(),
        hidden: all.first().cloned(),
        more: all.iter().skip(1).cloned().collect(),
        nominal,
        record,
        drive: drive_of(closed),
    })
}

/// How the diagnosis replays a case: the rig's PI force loop (`closed`) or the recorded
/// command.
fn drive_of(closed: bool) -> ehactl_ident::replay::Drive {
    if closed {
        ehactl_ident::replay::Drive::ForcePi {
            gains: force_pi_gains(),
            max_command: f64::INFINITY,
        }
    } else {
        ehactl_ident::replay::Drive::Recorded
    }
}

/// The hidden effects of `effects` (the variants joined by `+`, or `clean`), drawn in order
/// from `g`; an error names an unknown variant or two that change the same part of the
/// model. `kind` is the whole case name, for the messages.
fn draw_all(kind: &str, effects: &str, rig: &Rig, g: &mut Pcg) -> Result<Vec<Hidden>, String> {
    let mut all: Vec<Hidden> = Vec::new();
    if effects == "clean" {
        return Ok(all);
    }
    for name in effects.split('+') {
        let h = draw(name, rig, g)
            .ok_or_else(|| format!("unknown generator variant `{name}` in `{kind}`"))?;
        if let Some(o) = all.iter().find(|o| site(o) == site(&h)) {
            return Err(format!(
                "`{kind}`: {o:?} and {h:?} change the same part of the model ({})",
                site(&h)
            ));
        }
        all.push(h);
    }
    Ok(all)
}

/// The state the settling starts from: the piston mid-stroke, the chambers, hoses and line
/// nodes at the open-centre equilibrium estimate (half the supply pressure, Pa), the supply
/// at its pressure and a mounted load at the piston.
fn initial_state(model: &Model<'_>, rig: &Rig, sim: &[Hidden]) -> Vec<f64> {
    let mut y = vec![0.0; model.n];
    y[0] = 0.5 * rig.stroke;
    // Start at the open-centre equilibrium estimate, then settle.
    y[2] = 0.5 * rig.ps;
    y[3] = 0.5 * rig.ps;
    if model.i_ps != usize::MAX {
        y[model.i_ps] = rig.ps;
    }
    if model.i_line != usize::MAX {
        let ns = model.line.3;
        for j in 0..ns {
            y[model.i_line + j] = y[2];
            y[model.i_line + 2 * ns + j] = y[3];
        }
    }
    if model.i_hose != usize::MAX {
        y[model.i_hose] = y[2];
        y[model.i_hose + 1] = y[3];
    }
    if model.i_mount != usize::MAX && sim.iter().any(|h| matches!(h, Hidden::LoadMount { .. })) {
        y[model.i_mount] = y[0];
    }
    y
}

/// The classical fourth-order Runge–Kutta step of the model's state over `h` (s), with the
/// stage buffers it reuses.
struct Rk4 {
    k: [Vec<f64>; 4],
    tmp: Vec<f64>,
    h: f64,
}

impl Rk4 {
    /// Buffers for a state of `n` values, step `h` (s).
    fn new(n: usize, h: f64) -> Self {
        Self {
            k: [(); 4].map(|_| vec![0.0; n]),
            tmp: vec![0.0; n],
            h,
        }
    }

    /// One step of `y` at the command `uc` (V), then every pressure state held at or above
    /// the cavitation pressure [`P_CAV`] (Pa).
    fn step(&mut self, model: &Model<'_>, y: &mut [f64], uc: f64) {
        let (k, tmp, h) = (&mut self.k, &mut self.tmp, self.h);
        model.rhs(y, uc, &mut k[0]);
        for i in 0..y.len() {
            tmp[i] = y[i] + 0.5 * h * k[0][i];
        }
        model.rhs(tmp, uc, &mut k[1]);
        for i in 0..y.len() {
            tmp[i] = y[i] + 0.5 * h * k[1][i];
        }
        model.rhs(tmp, uc, &mut k[2]);
        for i in 0..y.len() {
            tmp[i] = y[i] + h * k[2][i];
        }
        model.rhs(tmp, uc, &mut k[3]);
        for i in 0..y.len() {
            y[i] += h / 6.0 * (k[0][i] + 2.0 * k[1][i] + 2.0 * k[2][i] + k[3][i]);
        }
        y[2] = y[2].max(P_CAV);
        y[3] = y[3].max(P_CAV);
        if model.i_hose != usize::MAX {
            y[model.i_hose] = y[model.i_hose].max(P_CAV);
            y[model.i_hose + 1] = y[model.i_hose + 1].max(P_CAV);
        }
        if model.i_line != usize::MAX {
            // Node pressures of side A at i_line.., of side B at i_line + 2·nseg...
            let ns = model.line.3;
            for j in 0..ns {
                for i in [model.i_line + j, model.i_line + 2 * ns + j] {
                    y[i] = y[i].max(P_CAV);
                }
            }
        }
    }
}

/// The hidden tone on one measured channel: the channel's index and (frequency Hz,
/// amplitude in the channel's unit, phase rad), if one is hidden.
struct Tone(usize, Option<(f64, f64, f64)>);

impl Tone {
    /// The tone among the simulated effects.
    fn of(sim: &[Hidden]) -> Self {
        let (ch, tone) = sim
            .iter()
            .find_map(|h| match h {
                Hidden::Tone { ch, f, a, phase } => Some((*ch, Some((*f, *a, *phase)))),
                _ => None,
            })
            .unwrap_or((usize::MAX, None));
        Tone(ch, tone)
    }

    /// What it adds to channel `c` at time `t` (s).
    fn at(&self, c: usize, t: f64) -> f64 {
        match self.1 {
            Some((f, a, ph)) if self.0 == c => a * (TAU * f * t + ph).sin(),
            _ => 0.0,
        }
    }
}

/// The state is finite and the piston within its `stroke` (m) at time `t` (s).
fn check_state(y: &[f64], stroke: f64, t: f64) -> Result<(), String> {
    if !y.iter().all(|v| v.is_finite()) {
        return Err(format!("state not finite at t = {t} s"));
    }
    if y[0] < 0.0 || y[0] > stroke {
        return Err(format!("piston left the stroke at t = {t} s"));
    }
    Ok(())
}

/// The record of the columns: time (s), command (V), force (N), position (m), pressures A
/// and B (Pa), the force setpoint (N) of a closed loop.
fn record_of(
    source: &str,
    t: Vec<f64>,
    u: Vec<f64>,
    cols: Vec<Vec<f64>>,
    reference: Option<Vec<f64>>,
) -> Result<Record, String> {
    let kinds = [
        ChannelKind::Force,
        ChannelKind::Position,
        ChannelKind::PressureA,
        ChannelKind::PressureB,
    ];
    let channels = kinds
        .iter()
        .zip(cols)
        .map(|(k, v)| Channel {
            kind: *k,
            values: v,
        })
        .collect();
    Record::from_columns(source, t, u, channels, reference, 0).map_err(|e| e.to_string())
}

/// Parse `bench/indep_cases.txt`: lines `seed kind`, `#` comments.
pub fn parse_cases(text: &str) -> Vec<(u64, String)> {
    text.lines()
        .map(|l| l.split('#').next().unwrap_or("").trim())
        .filter(|l| !l.is_empty())
        .filter_map(|l| {
            let mut it = l.split_whitespace();
            Some((it.next()?.parse().ok()?, it.next()?.to_string()))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// FNV-1a (64 bit) over the bit patterns of a case's record: time, command, reference,
    /// every channel, plus the drawn effects as printed.
    fn fingerprint(c: &Case) -> u64 {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        let mut eat = |bytes: &[u8]| {
            for b in bytes {
                h ^= u64::from(*b);
                h = h.wrapping_mul(0x0100_0000_01b3);
            }
        };
        let r = &c.record;
        for v in r.t.iter().chain(&r.u).chain(r.reference.iter().flatten()) {
            eat(&v.to_bits().to_le_bytes());
        }
        for ch in &r.channels {
            for v in &ch.values {
                eat(&v.to_bits().to_le_bytes());
            }
        }
        eat(format!("{:?} {:?}", c.hidden, c.more).as_bytes());
        h
    }

    /// The generator's records, bit for bit, as `generate_with` made them before it was split
    /// into steps (main 5a1f356, 2026-12-07): every variant once, open and closed loop, a
    /// combination and a driven case. `EHACTL_PRINT_FINGERPRINTS=1` prints the table.
    #[test]
    fn records_are_bit_identical_to_the_unsplit_generator() {
        let kinds = [
            "clean",
            "lugre",
            "dahl",
            "hose",
            "load_coulomb",
            "overlap",
            "amp_deadzone",
            "soft_saturation",
            "asym_saturation",
            "spool1",
            "spool2",
            "internal_leak",
            "external_leak_both",
            "external_leak_a",
            "entrained_air",
            "linear_beta",
            "lines",
            "load_mount",
            "body_mount",
            "delay",
            "tone",
            "supply_resistance",
            "pump_limit",
            "pi_clean",
            "pi_lugre+internal_leak",
            "pi_delay+tone",
            "overlap+external_leak_both",
        ];
        let mut got: Vec<(String, u64)> = kinds
            .iter()
            .enumerate()
            .map(|(i, k)| {
                let c =
                    make_case(9000 + i as u64, k, 0.2, 1e-3).unwrap_or_else(|e| panic!("{k}: {e}"));
                (k.to_string(), fingerprint(&c))
            })
            .collect();
        let excitation: Vec<f64> = (0..200).map(|i| (0.05 * i as f64).sin()).collect();
        let driven = make_case_small_driven(9100, "pi_lugre", 0.3, &excitation, 1e-3)
            .unwrap_or_else(|e| panic!("driven: {e}"));
        got.push(("driven pi_lugre α 0.3".into(), fingerprint(&driven)));
        if std::env::var_os("EHACTL_PRINT_FINGERPRINTS").is_some() {
            for (k, f) in &got {
                println!("            (\"{k}\", 0x{f:016x}),");
            }
        }
        let want: &[(&str, u64)] = &[
            ("clean", 0x335359e6d9063959),
            ("lugre", 0x7fcccedcc8db23ac),
            ("dahl", 0x1715746e2e73ad48),
            ("hose", 0x844d76f7736137e9),
            ("load_coulomb", 0x792f079e1c53742c),
            ("overlap", 0x35e28025a3df1606),
            ("amp_deadzone", 0xfd653f87cac7dd13),
            ("soft_saturation", 0xdc4d9daf655ff52f),
            ("asym_saturation", 0x2ace32e67839fa31),
            ("spool1", 0xb58c4a40c514aff0),
            ("spool2", 0x1d2ead71a4b1356f),
            ("internal_leak", 0xf1a951a0ab1cc73a),
            ("external_leak_both", 0x1679514f3702e363),
            ("external_leak_a", 0x99c3650114a35c36),
            ("entrained_air", 0x55a9b50cfe6f9ff4),
            ("linear_beta", 0x6203e819fedd387c),
            ("lines", 0x3d60053c3eaf520e),
            ("load_mount", 0xaa81b8fb70c28ba0),
            ("body_mount", 0x39954066911b65a4),
            ("delay", 0x82a7f39c4232d62f),
            ("tone", 0x97d8bbe61226ea37),
            ("supply_resistance", 0x9c02b7b246bf091c),
            ("pump_limit", 0x69095fe57770f8a6),
            ("pi_clean", 0xae957db8a0781d0f),
            ("pi_lugre+internal_leak", 0x4eac67ecb7e8314d),
            ("pi_delay+tone", 0x3c5b956539dc9787),
            ("overlap+external_leak_both", 0x63abd39cfc77b585),
            ("driven pi_lugre α 0.3", 0x65a6d82b9537b470),
        ];
        let got: Vec<(&str, u64)> = got.iter().map(|(k, f)| (k.as_str(), *f)).collect();
        assert_eq!(got, want);
    }
}
