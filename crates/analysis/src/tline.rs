//! Frequency-domain fluid transmission lines and the Sirohi 2003 piezohydraulic circuit.
//!
//! Sirohi 2003 (Sirohi & Chopra) treats every fluid passage as a distributed line with the
//! four-pole transfer matrix of eq. 1–2 between the pressure P (Pa) and the volume flow Q (m³/s)
//! at its ends, {P₂, Q₂} = T·{P₁, Q₁}, with the propagation operator Γ and the characteristic
//! impedance Z_c of the inviscid case (eq. 3–5) or of the dissipative viscous model (eq. 6–12,
//! Woods' first-order square-root approximation of the Bessel ratio B_r). The pump (eq. 13–15),
//! the accumulator (eq. 16–20) and the output piston (eq. 21–22) close the circuit; the output
//! displacement per volt of the piezo stack follows by harmonic substitution D = jω (eq. 11).
//!
//! Instead of assembling the 7×7 system of eq. 30–36 this module propagates the state from
//! the output piston back to the pump through the transfer matrices (the same equations, with
//! the check valves of eq. 23–24 set to R_out = 0, R_in = ∞ as in the paper's experiment).
//!
//! Note on eq. 10: the paper prints ω_v = 8ν/d². With the Bessel argument j√(8 D̄_v) of eq. 8
//! that reproduces the exact laminar-flow result only if d is the line *radius*: at low
//! frequency Γ² → s·ω_v·l²/c₀² must equal the Hagen–Poiseuille R·sC = s·32ν·l²/(d²c₀²)
//! (d = diameter), i.e. ω_v = 32ν/d² = 8ν/r². [`viscous_frequency`] uses 8ν/r²; the test
//! `dissipative_low_frequency_limit_is_hagen_poiseuille` checks that limit.

use nalgebra::Complex;
use std::f64::consts::PI;

/// One inch (m).
pub const INCH: f64 = 0.0254;
/// One psi (Pa).
pub const PSI: f64 = 6894.757;

type C64 = Complex<f64>;

/// Fluid properties (SI).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fluid {
    /// Density ρ (kg/m³).
    pub density: f64,
    /// Bulk modulus β (Pa).
    pub bulk_modulus: f64,
    /// Kinematic viscosity ν (m²/s).
    pub kinematic_viscosity: f64,
}

impl Fluid {
    /// Speed of sound c₀ = √(β/ρ) (m/s), 001 eq. 5.
    pub fn sound_speed(&self) -> f64 {
        (self.bulk_modulus / self.density).sqrt()
    }

    /// Sirohi 2003's MIL-H-5606 fluid: ρ 859 kg/m³ (Table 1 prints "859 g/cc", evidently
    /// 0.859 g/cc), β_ref 260 000 psi, and the given kinematic viscosity ν (m²/s); Table 1 gives
    /// 15 cSt, the experiments used a 2 cSt fluid.
    pub fn sirohi2003(kinematic_viscosity: f64) -> Self {
        Self {
            density: 859.0,
            bulk_modulus: 260_000.0 * PSI,
            kinematic_viscosity,
        }
    }
}

/// How the line's wall friction enters Γ and Z_c.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Friction {
    /// No viscosity: Γ = D/ω_c, Z_c = Z₀ (001 eq. 3–4).
    Inviscid,
    /// Linear friction with the steady Hagen–Poiseuille resistance R' = 128μ/(πd⁴) per metre and
    /// the plug-flow inertance ρ/A (the "linear friction model" 001 mentions before eq. 6; the
    /// continuum limit of the plant's lumped R-L-C line, 002 eq. 9–17):
    /// Γ = (l/c₀)·√(s(s + R'/L')), Z_c = Z₀·√(1 + R'/(sL')).
    Linear,
    /// Dissipative model with frequency-dependent viscous losses (001 eq. 6–12):
    /// Γ = (s·l/c₀)·(1 − B_r)^(−1/2), Z_c = Z₀·(1 − B_r)^(−1/2), B_r = (1 + 2s/ω_v)^(−1/2).
    Dissipative,
    /// As `Dissipative` with the exact laminar Bessel ratio B_r = 2·J₁(κ)/(κ·J₀(κ)),
    /// κ = j·√(8 D̄_v) (001 eq. 7–8 before Woods' approximation; [`bessel_ratio_exact`]).
    Bessel,
}

/// Viscous frequency ω_v = 8ν/r² (rad/s) of a line of hydraulic diameter `d` (m), 001 eq. 10
/// (see the module note on radius versus diameter).
pub fn viscous_frequency(kinematic_viscosity: f64, d: f64) -> f64 {
    let r = 0.5 * d;
    8.0 * kinematic_viscosity / (r * r)
}

/// Woods' first-order approximation of the Bessel ratio, B_r = 1/√(1 + 2D̄_v) with
/// D̄_v = s/ω_v (001 eq. 12), at the Laplace variable `s` (1/s).
pub fn bessel_ratio(s: C64, omega_v: f64) -> C64 {
    C64::new(1.0, 0.0) / (C64::new(1.0, 0.0) + s * (2.0 / omega_v)).sqrt()
}

/// Exact laminar Bessel ratio B_r = 2·J₁(κ)/(κ·J₀(κ)) = 2·I₁(x)/(x·I₀(x)), x = √(8s/ω_v)
/// (001 eq. 7–8), at the Laplace variable `s` (1/s). I₁/I₀ by its continued fraction
/// I_n/I_{n−1} = 1/(2n/x + I_{n+1}/I_n), evaluated backwards.
pub fn bessel_ratio_exact(s: C64, omega_v: f64) -> C64 {
    let one = C64::new(1.0, 0.0);
    let x = (s * (8.0 / omega_v)).sqrt();
    if x.norm() < 1e-4 {
        // 2I₁/(xI₀) = 1 − x²/8 + x⁴/48 − …
        let x2 = x * x;
        return one - x2 / 8.0 + x2 * x2 / 48.0;
    }
    let terms = (2.0 * x.norm()) as usize + 60;
    let mut ratio = C64::new(0.0, 0.0);
    for n in (1..=terms).rev() {
        ratio = one / (C64::new(2.0 * n as f64, 0.0) / x + ratio);
    }
    ratio * 2.0 / x
}

/// A 2×2 complex four-pole matrix acting on {P (Pa), Q (m³/s)} (001 eq. 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TransferMatrix(pub [[C64; 2]; 2]);

impl TransferMatrix {
    /// The identity.
    pub fn identity() -> Self {
        let (o, z) = (C64::new(1.0, 0.0), C64::new(0.0, 0.0));
        Self([[o, z], [z, o]])
    }

    /// Matrix product self·rhs (apply `rhs` first).
    pub fn then_after(&self, rhs: &Self) -> Self {
        let (a, b) = (&self.0, &rhs.0);
        let mut m = [[C64::new(0.0, 0.0); 2]; 2];
        for (i, row) in m.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = a[i][0] * b[0][j] + a[i][1] * b[1][j];
            }
        }
        Self(m)
    }

    /// Apply to {P, Q}.
    pub fn apply(&self, p: C64, q: C64) -> (C64, C64) {
        let m = &self.0;
        (m[0][0] * p + m[0][1] * q, m[1][0] * p + m[1][1] * q)
    }

    /// Inverse (general 2×2; a line matrix has determinant 1).
    pub fn inverse(&self) -> Self {
        let m = &self.0;
        let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
        Self([
            [m[1][1] / det, -m[0][1] / det],
            [-m[1][0] / det, m[0][0] / det],
        ])
    }

    /// Determinant.
    pub fn det(&self) -> C64 {
        let m = &self.0;
        m[0][0] * m[1][1] - m[0][1] * m[1][0]
    }
}

/// Point matrix of a lumped capacitance C (m³/Pa) at one station, 001 eq. 19–20:
/// P unchanged, Q₂ = Q₁ − sC·P (the accumulator, or any lumped volume V/β).
pub fn capacitance(s: C64, c: f64) -> TransferMatrix {
    let (o, z) = (C64::new(1.0, 0.0), C64::new(0.0, 0.0));
    TransferMatrix([[o, z], [-s * c, o]])
}

/// A uniform fluid line (tube, bore or chamber treated as a line).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineSection {
    /// Length l (m).
    pub length: f64,
    /// Flow area A (m²).
    pub area: f64,
    /// Hydraulic diameter for the viscous terms (m): the inner diameter of a tube.
    pub hydraulic_diameter: f64,
}

impl LineSection {
    /// A circular tube of inner diameter `d` (m) and length `length` (m).
    pub fn tube(length: f64, d: f64) -> Self {
        Self {
            length,
            area: 0.25 * PI * d * d,
            hydraulic_diameter: d,
        }
    }

    /// Compliance A·l/β of the whole line (m³/Pa).
    pub fn capacitance(&self, fluid: &Fluid) -> f64 {
        self.area * self.length / fluid.bulk_modulus
    }

    /// Propagation operator Γ (dimensionless, complex) and characteristic impedance Z_c
    /// (Pa·s/m³) at the Laplace variable `s` (1/s), 001 eq. 3–12.
    pub fn gamma_zc(&self, fluid: &Fluid, friction: Friction, s: C64) -> (C64, C64) {
        let c0 = fluid.sound_speed();
        let z0 = fluid.density * c0 / self.area;
        let d = self.hydraulic_diameter;
        let factor = match friction {
            Friction::Inviscid => C64::new(1.0, 0.0),
            Friction::Linear => {
                // R'/L' = (128μ/(πd⁴))/(ρ/A) = 32ν/d² (1/s).
                let r_over_l = 128.0 * fluid.kinematic_viscosity * self.area / (PI * d.powi(4));
                (C64::new(1.0, 0.0) + r_over_l / s).sqrt()
            }
            Friction::Dissipative => {
                let br = bessel_ratio(s, viscous_frequency(fluid.kinematic_viscosity, d));
                (C64::new(1.0, 0.0) / (C64::new(1.0, 0.0) - br)).sqrt()
            }
            Friction::Bessel => {
                let br = bessel_ratio_exact(s, viscous_frequency(fluid.kinematic_viscosity, d));
                (C64::new(1.0, 0.0) / (C64::new(1.0, 0.0) - br)).sqrt()
            }
        };
        (s * (self.length / c0) * factor, factor * z0)
    }

    /// Four-pole matrix of 001 eq. 2: {P₂, Q₂} = T·{P₁, Q₁} with
    /// T = [[cosh Γ, −Z_c sinh Γ], [−sinh Γ / Z_c, cosh Γ]].
    pub fn matrix(&self, fluid: &Fluid, friction: Friction, s: C64) -> TransferMatrix {
        if self.length <= 0.0 {
            return TransferMatrix::identity();
        }
        let (g, zc) = self.gamma_zc(fluid, friction, s);
        let (ch, sh) = (g.cosh(), g.sinh());
        TransferMatrix([[ch, -zc * sh], [-sh / zc, ch]])
    }
}

/// The piezo-stack pump of 001 eq. 13–15.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PiezoPump {
    /// Pumping piston area a_p (m²).
    pub piston_area: f64,
    /// Pumping chamber height Δ_gap (m), eq. 15.
    pub chamber_height: f64,
    /// Stack stiffness k_p (N/m).
    pub stiffness: f64,
    /// Stack force coefficient c_v (N/V).
    pub force_per_volt: f64,
    /// Moving mass m_p of piston, diaphragm and stack (kg).
    pub mass: f64,
    /// Damping b_p (N·s/m).
    pub damping: f64,
}

impl PiezoPump {
    /// Pumping chamber capacitance C_c = a_p·Δ_gap/β (m³/Pa), 001 eq. 15.
    pub fn chamber_capacitance(&self, fluid: &Fluid) -> f64 {
        self.piston_area * self.chamber_height / fluid.bulk_modulus
    }

    /// Static equivalent oil volume of chamber plus stack compliance, a_p·Δ_gap + β·a_p²/k_p
    /// (m³): the lumped `port_volume` that makes a flow-source circuit equivalent below the
    /// stack's own resonance √(k_p/m_p).
    pub fn equivalent_volume(&self, fluid: &Fluid) -> f64 {
        self.piston_area * self.chamber_height
            + fluid.bulk_modulus * self.piston_area * self.piston_area / self.stiffness
    }

    /// Sirohi 2003's pump. From Table 1 and the text: 1 in piston, 0.050 in chamber height, two
    /// P-804.10 stacks in series, each 1133 lb blocked force and ≈ 0.5 mil free stroke at
    /// 0–100 V, so k_p = ½·F_b/x_f ≈ 1.98e8 N/m and c_v = F_b/100 V ≈ 50.4 N/V.
    /// Assumed (001 silent): m_p = 0.035 kg (25 g steel piston, 1 in × ¼ in, plus a third of
    /// the ≈ 28 g of stacks), b_p = 0, the 0.002 in diaphragm's stiffness neglected.
    pub fn sirohi2003() -> Self {
        let blocked = 1133.0 * 4.448_222; // N
        let free = 0.5e-3 * INCH; // m
        Self {
            piston_area: 0.25 * PI * INCH * INCH,
            chamber_height: 0.050 * INCH,
            stiffness: 0.5 * blocked / free,
            force_per_volt: blocked / 100.0,
            mass: 0.035,
            damping: 0.0,
        }
    }
}

/// What drives the circuit at the pumping-chamber end of the line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Source {
    /// The piezo pump driven by the stack voltage (input: V); the check valve to the line
    /// permanently open (R_out = 0), the other closed (R_in = ∞), as in 001's experiment.
    Pump(PiezoPump),
    /// An ideal flow source (input: m³/s) into a lumped port volume (m³) at the line inlet:
    /// the circuit a critically centred valve at null realises in the plant.
    Flow {
        /// Lumped volume at the line inlet (m³), compressed with the fluid β.
        port_volume: f64,
    },
}

/// A cylinder chamber between the line and the piston.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Chamber {
    /// Treated as a line of the bore's annular area (001's T_lc, T_uc).
    Line(LineSection),
    /// A lumped volume V (m³), capacitance V/β (the plant's chambers).
    Volume(f64),
}

impl Chamber {
    fn matrix(&self, fluid: &Fluid, friction: Friction, s: C64) -> TransferMatrix {
        match self {
            Chamber::Line(l) => l.matrix(fluid, friction, s),
            Chamber::Volume(v) => capacitance(s, v / fluid.bulk_modulus),
        }
    }
}

/// The output cylinder with its load, 001 eq. 21–22.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OutputCylinder {
    /// Piston area a_o on each face (m²), double rod.
    pub area: f64,
    /// High-pressure chamber between the line and the piston (001's T_lc).
    pub high_chamber: Chamber,
    /// Return-side chamber between the piston and the accumulator (001's T_uc).
    pub low_chamber: Chamber,
    /// Moving mass m_o of piston, rods and load (kg).
    pub mass: f64,
    /// Damping b_o (N·s/m).
    pub damping: f64,
    /// Load stiffness k_o (N/m).
    pub stiffness: f64,
}

impl OutputCylinder {
    /// Sirohi 2003's output cylinder: double rod, 7/16 in bore, 3/16 in shaft, 2 in stroke, at
    /// mid-stroke (each chamber 1 in long, treated as a line of the annular area with the
    /// annulus' hydraulic diameter bore − shaft). Assumed (001 silent): m_o = 0.030 kg
    /// (steel piston 7/16 × 3/8 in plus a 6 in long 3/16 in shaft), b_o = 0 (seal friction is
    /// Coulomb/stick-slip, which 001 reports as unmodelled), k_o = 0 (unloaded shaft under
    /// the vibrometer).
    pub fn sirohi2003() -> Self {
        let bore = 0.4375 * INCH;
        let shaft = 0.1875 * INCH;
        let area = 0.25 * PI * (bore * bore - shaft * shaft);
        let chamber = LineSection {
            length: 1.0 * INCH,
            area,
            hydraulic_diameter: bore - shaft,
        };
        Self {
            area,
            high_chamber: Chamber::Line(chamber),
            low_chamber: Chamber::Line(chamber),
            mass: 0.030,
            damping: 0.0,
            stiffness: 0.0,
        }
    }
}

/// The piezohydraulic circuit of 001 fig. 3 with its flow rectification removed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Circuit {
    /// Hydraulic fluid.
    pub fluid: Fluid,
    /// Line friction model for every line section.
    pub friction: Friction,
    /// Pump (or flow source) side.
    pub source: Source,
    /// Tube between the pump and the output manifold (length 0: pump on the manifold).
    pub tube: LineSection,
    /// Output cylinder and load.
    pub cylinder: OutputCylinder,
    /// Accumulator capacitance C_acc (m³/Pa) behind the return chamber; `f64::INFINITY` is an
    /// ideal accumulator holding the bias pressure (001 eq. 16–20 with C_acc ≫ the lines').
    pub accumulator: f64,
}

/// Output of the circuit at one frequency, per unit input (V for a pump, m³/s for a flow
/// source).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Response {
    /// Frequency (Hz).
    pub f_hz: f64,
    /// Output piston displacement x_o (m per input unit).
    pub displacement: C64,
    /// Pressure at the line inlet, the pumping chamber P_c (Pa per input unit).
    pub source_pressure: C64,
}

impl Response {
    /// Output piston velocity jω·x_o (m/s per input unit).
    pub fn velocity(&self) -> C64 {
        self.displacement * C64::new(0.0, 2.0 * PI * self.f_hz)
    }
}

/// Inner diameter of 001's 1/8 in OD × 0.028 in wall tubing, 0.069 in (m).
pub const SIROHI_TUBE_ID: f64 = (0.125 - 2.0 * 0.028) * INCH;

impl Circuit {
    /// Sirohi 2003's device with a tube of `tube_length` (m; 001: 0, 4.5, 11.5 in) of
    /// 1/8 in × 0.028 in wall tubing, fluid viscosity ν (m²/s), the dissipative line model of
    /// eq. 6–12 and an ideal accumulator (001 gives neither its size nor the return-side
    /// passages; with R_in = ∞ they only matter through C_acc, taken ≫ the lines').
    pub fn sirohi2003(tube_length: f64, kinematic_viscosity: f64) -> Self {
        Self {
            fluid: Fluid::sirohi2003(kinematic_viscosity),
            friction: Friction::Dissipative,
            source: Source::Pump(PiezoPump::sirohi2003()),
            tube: LineSection::tube(tube_length, SIROHI_TUBE_ID),
            cylinder: OutputCylinder::sirohi2003(),
            accumulator: f64::INFINITY,
        }
    }

    /// Response at `f_hz` (Hz), D = jω (001 eq. 11).
    pub fn response(&self, f_hz: f64) -> Response {
        let w = 2.0 * PI * f_hz;
        let s = C64::new(0.0, w);
        let fl = &self.fluid;
        let cyl = &self.cylinder;
        // Return side: piston face → low chamber → accumulator at P_acc = Q_acc/(sC_acc).
        let q_up = s * cyl.area; // per unit x_o, eq. 22
        let t_uc = cyl.low_chamber.matrix(fl, self.friction, s);
        let m = &t_uc.0;
        // {P_acc, Q_acc} = T_uc·{P_up, Q_up} and P_acc = Z_acc·Q_acc, solved for P_up.
        let p_up = if self.accumulator.is_infinite() {
            -m[0][1] * q_up / m[0][0]
        } else {
            let z_acc = C64::new(1.0, 0.0) / (s * self.accumulator);
            (z_acc * m[1][1] - m[0][1]) * q_up / (m[0][0] - z_acc * m[1][0])
        };
        // Piston, eq. 21: (P_lp − P_up)·a_o = (m_o s² + b_o s + k_o)·x_o.
        let z_o = s * s * cyl.mass + s * cyl.damping + cyl.stiffness;
        let p_lp = p_up + z_o / cyl.area;
        let q_lp = s * cyl.area;
        // Back through the high chamber and the tube to the line inlet (station 1).
        let t_lc = cyl.high_chamber.matrix(fl, self.friction, s);
        let t_lt = self.tube.matrix(fl, self.friction, s);
        let forward = t_lc.then_after(&t_lt); // {P_lp, Q_lp} = T_lc·T_lt·{P_1, Q_1}
        let (p1, q1) = forward.inverse().apply(p_lp, q_lp);
        // Source: Q_1 = Q_s − Y_in·P_1 (eq. 13–15 with R_out = 0, Q_4 = 0).
        let (q_s, y_in) = match self.source {
            Source::Pump(p) => {
                let z_p = s * s * p.mass + s * p.damping + p.stiffness;
                (
                    s * p.piston_area * p.force_per_volt / z_p,
                    s * p.chamber_capacitance(fl) + s * p.piston_area * p.piston_area / z_p,
                )
            }
            Source::Flow { port_volume } => {
                (C64::new(1.0, 0.0), s * (port_volume / fl.bulk_modulus))
            }
        };
        let x_o = q_s / (q1 + y_in * p1);
        Response {
            f_hz,
            displacement: x_o,
            source_pressure: p1 * x_o,
        }
    }
}

/// A resonance: the frequency of a local maximum of a gain and the gain there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Peak {
    /// Frequency (Hz).
    pub f_hz: f64,
    /// Gain at the peak (units of the gain function).
    pub gain: f64,
}

/// The first (lowest-frequency) local maximum of `gain(f)` in (`f_lo`, `f_hi`) Hz: a scan
/// over `points` log-spaced frequencies, then golden-section refinement to 1e-6 relative.
/// `None` if the gain has no interior maximum in the band.
pub fn first_peak(gain: impl Fn(f64) -> f64, f_lo: f64, f_hi: f64, points: usize) -> Option<Peak> {
    let n = points.max(3);
    let r = (f_hi / f_lo).ln() / (n - 1) as f64;
    let f = |i: usize| f_lo * (r * i as f64).exp();
    let mut prev2 = gain(f(0));
    let mut prev1 = gain(f(1));
    for i in 2..n {
        let g = gain(f(i));
        if prev1 > prev2 && prev1 >= g {
            // Golden section on ln f in [f(i−2), f(i)].
            let (mut a, mut b) = (f(i - 2).ln(), f(i).ln());
            let k = 0.5 * (5f64.sqrt() - 1.0);
            let mut c = b - k * (b - a);
            let mut d = a + k * (b - a);
            let (mut gc, mut gd) = (gain(c.exp()), gain(d.exp()));
            while (b - a) > 1e-6 {
                if gc > gd {
                    b = d;
                    d = c;
                    gd = gc;
                    c = b - k * (b - a);
                    gc = gain(c.exp());
                } else {
                    a = c;
                    c = d;
                    gc = gd;
                    d = a + k * (b - a);
                    gd = gain(d.exp());
                }
            }
            let fm = (0.5 * (a + b)).exp();
            return Some(Peak {
                f_hz: fm,
                gain: gain(fm),
            });
        }
        prev2 = prev1;
        prev1 = g;
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn line_matrix_has_unit_determinant() {
        let fl = Fluid::sirohi2003(2e-6);
        let l = LineSection::tube(0.3, SIROHI_TUBE_ID);
        for fr in [Friction::Inviscid, Friction::Linear, Friction::Dissipative] {
            for f in [1.0, 100.0, 3000.0] {
                let t = l.matrix(&fl, fr, C64::new(0.0, 2.0 * PI * f));
                assert!((t.det() - C64::new(1.0, 0.0)).norm() < 1e-9, "{fr:?} {f}");
            }
        }
    }

    #[test]
    fn dissipative_low_frequency_limit_is_hagen_poiseuille() {
        // Γ·Z_c → (R + sL)·l and Γ/Z_c → sC·l as s → 0: the series impedance per length
        // tends to the Hagen–Poiseuille resistance 128μ/(πd⁴).
        let fl = Fluid::sirohi2003(20e-6);
        let d = SIROHI_TUBE_ID;
        let l = LineSection::tube(1.0, d);
        let s = C64::new(0.0, 1e-4 * viscous_frequency(fl.kinematic_viscosity, d));
        let (g, zc) = l.gamma_zc(&fl, Friction::Dissipative, s);
        let r_hp = 128.0 * fl.density * fl.kinematic_viscosity / (PI * d.powi(4));
        let series = g * zc;
        assert!(
            (series.re / r_hp - 1.0).abs() < 1e-3,
            "{}",
            series.re / r_hp
        );
        let shunt = g / zc;
        let c = l.capacitance(&fl);
        assert!((shunt.im / (s.im * c) - 1.0).abs() < 1e-6);
    }

    #[test]
    fn inviscid_short_line_is_inertance_and_capacitance() {
        let fl = Fluid::sirohi2003(2e-6);
        let l = LineSection::tube(0.01, SIROHI_TUBE_ID);
        let s = C64::new(0.0, 2.0 * PI * 50.0);
        let t = l.matrix(&fl, Friction::Inviscid, s);
        let inert = fl.density * l.length / l.area;
        assert!(((-t.0[0][1]) / (s * inert) - C64::new(1.0, 0.0)).norm() < 1e-6);
        assert!(((-t.0[1][0]) / (s * l.capacitance(&fl)) - C64::new(1.0, 0.0)).norm() < 1e-6);
    }

    #[test]
    fn first_peak_of_a_second_order_system() {
        // |1/(1 − (f/f0)² + 2jζ f/f0)| peaks at f0·√(1 − 2ζ²).
        let (f0, z) = (200.0, 0.1);
        let g = |f: f64| {
            let r = f / f0;
            1.0 / C64::new(1.0 - r * r, 2.0 * z * r).norm()
        };
        let p = first_peak(g, 10.0, 1000.0, 200).unwrap();
        let exact = f0 * (1.0 - 2.0 * z * z).sqrt();
        assert!((p.f_hz / exact - 1.0).abs() < 1e-5, "{}", p.f_hz);
    }

    #[test]
    fn rigid_lossless_limit_matches_the_lumped_mass_spring() {
        // With the tube absent, inviscid fluid and chambers as lumped volumes, the circuit is a
        // single mass m_o on the series stiffness of chamber fluid and stack:
        // 1/k = C_tot/a_o² with C_tot = C_c + a_p²/k_p + V_lc/β (m_p = 0).
        let mut c = Circuit::sirohi2003(0.0, 2e-6);
        c.friction = Friction::Inviscid;
        if let Source::Pump(ref mut p) = c.source {
            p.mass = 0.0;
        }
        let v_lc = c.cylinder.area * INCH;
        c.cylinder.high_chamber = Chamber::Volume(v_lc);
        c.cylinder.low_chamber = Chamber::Volume(0.0);
        let p = PiezoPump::sirohi2003();
        let fl = c.fluid;
        let c_tot = p.chamber_capacitance(&fl)
            + p.piston_area * p.piston_area / p.stiffness
            + v_lc / fl.bulk_modulus;
        let k = c.cylinder.area * c.cylinder.area / c_tot;
        let f_n = (k / c.cylinder.mass).sqrt() / (2.0 * PI);
        // Undamped: the gain diverges at f_n; the scan's first maximum brackets it.
        let pk = first_peak(|f| c.response(f).displacement.norm(), 100.0, 5000.0, 4001).unwrap();
        assert!((pk.f_hz / f_n - 1.0).abs() < 1e-3, "{} vs {}", pk.f_hz, f_n);
    }

    #[test]
    fn exact_bessel_ratio_matches_reference_values() {
        // 2I₁(x)/(xI₀(x)), x = √(8jω/ω_v), from SciPy's `ive` (independent implementation).
        let cases = [
            (0.1, 0.986_915_244_439_609_3, -0.098_201_045_862_086_4),
            (1.0, 0.536_533_661_390_937_7, -0.369_308_373_043_373_2),
            (100.0, 0.050_008_218_264_384_94, -0.048_742_204_446_318_244),
            (
                1000.0,
                0.015_811_639_308_252_644,
                -0.015_686_141_297_771_444,
            ),
        ];
        for (w, re, im) in cases {
            let b = bessel_ratio_exact(C64::new(0.0, w * 3.0), 3.0);
            assert!(
                (b - C64::new(re, im)).norm() < 1e-12 * C64::new(re, im).norm().max(1e-3),
                "{w}: {b}"
            );
        }
        // Woods' approximation agrees at high frequency only.
        let far = C64::new(0.0, 1e6);
        assert!((bessel_ratio(far, 1.0) / bessel_ratio_exact(far, 1.0) - 1.0).norm() < 1e-3);
    }
}
