//! Actuator motion estimated from pressures measured at the valve ports (Cristofori 2015).
//!
//! Cristofori & Vacca estimate the piston motion of a crane boom without a position sensor:
//! 1. flow model (002 eq. 1–8): the workport flows Q_W from the solenoid command through the
//!    spool dynamics H(s) and the orifice equations of the metering edges, with the measured
//!    supply, tank and workport pressures;
//! 2. cylinder pressure model (eq. 9–17): the line between valve and cylinder as one R-L-C
//!    section (fig. 8), giving chamber pressure p_C and chamber flow Q_C from p_W and Q_W;
//! 3. actuator dynamics (eq. 27–36): the pressure build-up of a chamber solved for the piston
//!    position by finite differences, eq. 31 (extension chamber) or eq. 32 (retraction
//!    chamber), with the pressure-dependent bulk modulus β = K_b·p + β₀ of eq. 35–36.
//!
//! With counterbalance valves (`effects.counterbalance_valve`), flow into a chamber passes the
//! CBV's free-flow check: p_C loses p_crack + R_UV·Q_C² more (002 eq. 18–19, "case 1"; the
//! cracking term is the plant's check spring, 0 in 002). At stop (I = 0: every metering edge
//! of the valve closed, 002 "case 3") a side with a CBV keeps its last chamber pressure with no
//! flow (eq. 25 with the volume held, so the estimate stands still; eq. 26's p_Cr = p_Wr needs
//! the retraction CBV pilot-opened at stop, which a valve with a neutral A,B→T bleed does not
//! do). Flow out through the pilot-operated relief (002 "case 2", eq. 20–24) is not
//! implemented: with 002's switching (eq. 31 while raising and after lowering, eq. 32
//! otherwise) the side in use while moving is always the one fed through its check. The
//! valve's neutral bleed (`port_bleed`) is part of the characterised valve law.
//!
//! The flow model here is the plant's own valve law (`ehactl_plant::valve`), i.e. a perfectly
//! characterised valve, as 002 characterises its valve on a test bench (its section
//! "Experimental characterization of the proportional valve"). Friction never enters: its
//! effect is in the measured pressures (002's point).

use ehactl_plant::params::PlantParams;
use ehactl_plant::valve::{Deadband, EdgeLaw, Saturation, SpoolModel};

/// One lumped R-L-C line section (002 eq. 9–13): capacitance C at the valve port, then
/// inductance L and resistance R in series to the chamber.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineRlc {
    /// Laminar resistance R = 128·μ·l/(π·d⁴) (Pa·s/m³), eq. 9.
    pub r: f64,
    /// Inductance L = ρ·l/A (kg/m⁴), eq. 13.
    pub l: f64,
    /// Capacitance C = A·l/β (m³/Pa), eq. 11.
    pub c: f64,
}

impl LineRlc {
    /// A line of `length` (m) and inner diameter `d` (m) for a fluid of density ρ (kg/m³),
    /// kinematic viscosity ν (m²/s) and effective bulk modulus β (Pa).
    pub fn new(length: f64, d: f64, density: f64, nu: f64, beta: f64) -> Self {
        let area = 0.25 * std::f64::consts::PI * d * d;
        Self {
            r: 128.0 * density * nu * length / (std::f64::consts::PI * d.powi(4)),
            l: density * length / area,
            c: area * length / beta,
        }
    }

    /// No line: chamber pressure equals port pressure.
    pub fn none() -> Self {
        Self {
            r: 0.0,
            l: 0.0,
            c: 0.0,
        }
    }
}

/// Which terms of the line model (002 eq. 14–17) the cylinder pressure model keeps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LineTerms {
    /// R, L and C: p_C = p_W − R·Q_C − L·Q̇_C with Q_C = Q_W − C·ṗ_W (eq. 14–17); needs ṗ_W and
    /// p̈_W, so it amplifies pressure-sensor noise.
    Full,
    /// Resistance only, p_C = p_W − R·Q_W, Q_C = Q_W: 002's simplification for lines of
    /// limited volume ("neglecting capacitive and inductive contribution"), used for its results.
    Resistive,
}

/// Pressure-dependent bulk modulus β(p) = K_b·p + β₀, capped at `max` (002 eq. 35–36).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BulkModulusLaw {
    /// β at 0 bar gauge, β_(p=0) (Pa).
    pub beta0: f64,
    /// Slope K_b = ∂β/∂p (-).
    pub slope: f64,
    /// Upper bound (Pa).
    pub max: f64,
}

impl BulkModulusLaw {
    /// β (Pa) at gauge pressure `p` (Pa); negative pressures count as 0.
    pub fn beta(&self, p: f64) -> f64 {
        (self.beta0 + self.slope * p.max(0.0)).min(self.max)
    }

    /// The law a plant config uses (constant β₀ without `bulk_modulus_pressure`).
    pub fn from_params(p: &PlantParams) -> Self {
        match p
            .effects
            .bulk_modulus_pressure
            .as_ref()
            .filter(|b| b.enabled)
        {
            Some(b) => Self {
                beta0: p.fluid.bulk_modulus,
                slope: b.slope,
                max: b.max,
            },
            None => Self {
                beta0: p.fluid.bulk_modulus,
                slope: 0.0,
                max: f64::INFINITY,
            },
        }
    }
}

/// Signals one sample of the estimator reads: the command and pressures at the valve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PortSample {
    /// Valve command (V), 002's solenoid current I normalised to the command full scale.
    pub command: f64,
    /// Supply pressure p_P (Pa).
    pub p_supply: f64,
    /// Tank pressure p_T (Pa).
    pub p_tank: f64,
    /// Extension workport pressure p_We (Pa), port A.
    pub p_we: f64,
    /// Retraction workport pressure p_Wr (Pa), port B.
    pub p_wr: f64,
}

/// The estimator's output for one sample.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MotionEstimate {
    /// Workport flows into the lines, Q_We and Q_Wr (m³/s), eq. 7–8.
    pub q_w: [f64; 2],
    /// Chamber pressures p_Ce, p_Cr (Pa), eq. 14–15.
    pub p_c: [f64; 2],
    /// Chamber inflows Q_Ce, Q_Cr (m³/s), eq. 16–17.
    pub q_c: [f64; 2],
    /// Bulk moduli β_e,k and β_r,k (Pa), eq. 35–36.
    pub beta: [f64; 2],
    /// Piston position from the extension chamber (eq. 31) and from the retraction chamber
    /// (eq. 32) (m).
    pub x: [f64; 2],
    /// Piston velocity (x_k − x_(k−1))/Δt from each (m/s).
    pub v: [f64; 2],
}

/// Per-chamber finite-difference state.
#[derive(Debug, Clone, Copy, Default)]
struct Side {
    p_w: f64,
    q_l: f64,
    p_c: f64,
    q_c: f64,
    x: f64,
    /// CBV side isolated since the last stop (check shut), eq. 25.
    held: bool,
}

/// The estimator of 002 eq. 1–36 at a fixed sample period.
#[derive(Debug, Clone)]
pub struct MotionEstimator {
    dt: f64,
    full_scale: f64,
    spool_model: SpoolModel,
    edges: EdgeLaw,
    /// The edges' lap and limit stages (`valve_deadband`, `valve_saturation`).
    stages: (Deadband, Saturation),
    line: LineRlc,
    terms: LineTerms,
    beta: BulkModulusLaw,
    area: [f64; 2],
    /// V_Ce,min and V_Cr,max (m³), eq. 27–28.
    volume: [f64; 2],
    spool: f64,
    spool_velocity: f64,
    sides: [Side; 2],
    started: bool,
    /// CBV check of each side: (R_UV Pa·s²/m⁶, p_crack Pa), eq. 18–19.
    check: [Option<(f64, f64)>; 2],
    /// Work port → tank bleed of the valve (m³/(s·Pa)) with the CBVs.
    bleed: f64,
}

impl MotionEstimator {
    /// Estimator for a rig described by plant parameters `p`, sampled every `dt` (s), with
    /// the piston known to be at rest at `x0` (m) at the first sample (002: a known end stop).
    /// The line is one R-L-C section over the whole `line_dynamics` length (002's "simple
    /// transmission line"); without lines the chamber pressure is the port pressure.
    /// `Err` names the field of a spool that cannot be discretised at `dt`.
    pub fn new(p: &PlantParams, dt: f64, x0: f64) -> Result<Self, ehactl_plant::spec::ConfigError> {
        let beta = BulkModulusLaw::from_params(p);
        let line = p
            .effects
            .line_dynamics
            .as_ref()
            .filter(|l| l.enabled)
            .map_or(LineRlc::none(), |l| {
                LineRlc::new(
                    l.length,
                    l.diameter,
                    p.fluid.density,
                    p.fluid.kinematic_viscosity,
                    l.bulk_modulus.unwrap_or(p.fluid.bulk_modulus),
                )
            });
        let cyl = &p.cylinder;
        let cbv = p
            .effects
            .counterbalance_valve
            .as_ref()
            .filter(|c| c.enabled);
        let check = [
            ehactl_plant::cbv::CbvSides::A,
            ehactl_plant::cbv::CbvSides::B,
        ]
        .map(|side| {
            cbv.filter(|c| c.sides == side || c.sides == ehactl_plant::cbv::CbvSides::Both)
                .map(|c| (c.check_resistance, c.check_cracking))
        });
        let mut s = Self {
            check,
            bleed: cbv.map_or(0.0, |c| c.port_bleed),
            dt,
            full_scale: p.valve.command_full_scale,
            spool_model: SpoolModel::new(p.effects.valve_dynamics.as_ref(), dt)?,
            edges: EdgeLaw::new(p),
            stages: EdgeLaw::stages(p),
            line,
            terms: LineTerms::Resistive,
            beta,
            area: [cyl.area_a, cyl.area_b],
            volume: [
                cyl.dead_volume_a,
                cyl.dead_volume_b + cyl.area_b * cyl.stroke,
            ],
            spool: 0.0,
            spool_velocity: 0.0,
            sides: [Side::default(); 2],
            started: false,
        };
        s.sides.iter_mut().for_each(|d| d.x = x0);
        Ok(s)
    }

    /// Choose the line terms of the cylinder pressure model (default [`LineTerms::Resistive`], 002's choice).
    pub fn with_line_terms(mut self, terms: LineTerms) -> Self {
        self.terms = terms;
        self
    }

    /// The lumped line used by the cylinder pressure model.
    pub fn line(&self) -> LineRlc {
        self.line
    }

    /// The bulk-modulus law of eq. 35–36.
    pub fn bulk_modulus_law(&self) -> BulkModulusLaw {
        self.beta
    }

    /// Process one sample (call every `dt`, in order). The command is the one held over the
    /// interval that ends at this sample.
    pub fn update(&mut self, m: &PortSample) -> MotionEstimate {
        // Flow model, eq. 1–8: spool through H(s) (exact ZOH over dt), then the edges.
        self.spool_model.advance(
            &mut self.spool,
            &mut self.spool_velocity,
            m.command / self.full_scale,
        );
        let (lap, limit) = (&self.stages.0, &self.stages.1);
        let o = self.edges.openings(lap, limit, self.spool);
        let (q_we, _, _) = self
            .edges
            .port(limit, o[0], o[1], m.p_supply, m.p_tank, m.p_we);
        let (q_wr, _, _) = self
            .edges
            .port(limit, o[2], o[3], m.p_supply, m.p_tank, m.p_wr);
        let q_we = q_we - self.bleed * (m.p_we - m.p_tank);
        let q_wr = q_wr - self.bleed * (m.p_wr - m.p_tank);
        let stopped = o.iter().all(|&x| x <= 0.0);
        let dt = self.dt;
        let ln = match self.terms {
            LineTerms::Full => self.line,
            LineTerms::Resistive => LineRlc {
                c: 0.0,
                l: 0.0,
                ..self.line
            },
        };
        let mut out = MotionEstimate::default();
        for (i, (p_w, q_w)) in [(m.p_we, q_we), (m.p_wr, q_wr)].into_iter().enumerate() {
            let prev = self.sides[i];
            let first = !self.started;
            // Cylinder pressure model, eq. 9–17: Q_C = Q_W − C·ṗ_W; p_C = p_W − R·Q_C − L·Q̇_C.
            let dp_w = if first { 0.0 } else { (p_w - prev.p_w) / dt };
            let q_l = q_w - ln.c * dp_w;
            let dq_l = if first { 0.0 } else { (q_l - prev.q_l) / dt };
            // CBV free-flow check for flow into the chamber, eq. 18–19.
            let check = match self.check[i] {
                Some((r_uv, crack)) if q_l > 0.0 => crack + r_uv * q_l * q_l,
                _ => 0.0,
            };
            let p_in = p_w - ln.r * q_l - ln.l * dq_l - check;
            let cbv = self.check[i].is_some() && !first;
            // Case 3 (eq. 25): at stop the CBV isolates the chamber; it stays isolated until
            // the valve feeds it above the held pressure (the check opens, case 1).
            let held = cbv && (stopped || (prev.held && !(q_l > 0.0 && p_in >= prev.p_c)));
            let (p_c, q_c) = if held { (prev.p_c, 0.0) } else { (p_in, q_l) };
            let beta = self.beta.beta(p_c);
            let a = self.area[i];
            let x = if first {
                prev.x
            } else {
                // Chamber continuity over [k−1, k] with the mean inflow, solved for x_k.
                let q = 0.5 * (q_c + prev.q_c);
                let dp = p_c - prev.p_c;
                if i == 0 {
                    // eq. 31/33: (V_min + A·x_k)·Δp = β·Δt·Q − β·A·(x_k − x_(k−1)).
                    (beta * dt * q + beta * a * prev.x - self.volume[0] * dp) / (a * (dp + beta))
                } else {
                    // eq. 32/34: (V_max − A·x_k)·Δp = β·Δt·Q + β·A·(x_k − x_(k−1)).
                    (beta * a * prev.x + self.volume[1] * dp - beta * dt * q) / (a * (dp + beta))
                }
            };
            out.q_w[i] = q_w;
            out.p_c[i] = p_c;
            out.q_c[i] = q_c;
            out.beta[i] = beta;
            out.x[i] = x;
            out.v[i] = if first { 0.0 } else { (x - prev.x) / dt };
            self.sides[i] = Side {
                p_w,
                q_l,
                p_c,
                q_c,
                x,
                held,
            };
        }
        self.started = true;
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bulk_modulus_law_is_linear_then_capped() {
        let b = BulkModulusLaw {
            beta0: 1.4e9,
            slope: 7.0,
            max: 2.0e9,
        };
        assert_eq!(b.beta(-1e5), 1.4e9);
        assert!((b.beta(10e6) - 1.47e9).abs() < 1.0);
        assert_eq!(b.beta(1e9), 2.0e9);
    }

    #[test]
    fn line_constants_follow_eq_9_to_13() {
        // 1 m of Ø10 mm line, ρ 870, ν 46 cSt, β 1e9: R = 128μl/(πd⁴), L = ρl/A, C = Al/β.
        let l = LineRlc::new(1.0, 0.01, 870.0, 46e-6, 1e9);
        let a = 0.25 * std::f64::consts::PI * 1e-4;
        assert!(
            (l.r / (128.0 * 870.0 * 46e-6 / (std::f64::consts::PI * 1e-8)) - 1.0).abs() < 1e-12
        );
        assert!((l.l / (870.0 / a) - 1.0).abs() < 1e-12);
        assert!((l.c / (a / 1e9) - 1.0).abs() < 1e-12);
    }
}
