//! `line_dynamics`: lumped R-L-C segments between the valve ports and the chambers
//! (001, 002 eq. 9–17), rigid pipes or compliant hoses (variant `hose`; Merritt 1967,
//! "Hydraulic Control Systems", §2.7 eq. 2-46): the config section [`LineDynamics`]
//! (`[effects.line_dynamics]`) with its wall-friction model [`LineFriction`]. The segment
//! chains themselves are [`line::Line`] in crates/plant/src/effects/line_dynamics/line.rs (it
//! reads the fluid as plain numbers), re-exported as `crate::line`; the component [`Lines`]
//! holds the two chains (valve port A → chamber A, port B → chamber B) as its state and is
//! the [`LineStage`] the plant's substep calls (crates/plant/src/model.rs).

pub mod line;

use super::component::{phi1, Component, EndNode, LineStage, Setup};
use super::switch::yes;
use crate::spec::ConfigError;
use ehactl_params_derive::Params;
use line::Line;
use serde::{Deserialize, Serialize};

/// Structural variant of `line_dynamics`.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum LineVariant {
    /// Rigid pipe: segment capacitance A·ℓ/β with β the fluid's (or `bulk_modulus`),
    /// Hagen–Poiseuille resistance (002 eq. 9–17).
    #[default]
    Pipe,
    /// Compliant hose: the wall adds its compliance to the oil's, 1/β_eff = 1/β + `wall_compliance`
    /// (thin wall: D/(t·E), Merritt 1967, "Hydraulic Control Systems", §2.7 eq. 2-46; or a
    /// hose maker's volumetric expansion ΔV/(V·Δp)), and the hose ends / fittings add a
    /// laminar `resistance` between valve and chamber on top of the Hagen–Poiseuille one.
    Hose,
}

/// `line_dynamics`: lumped R-L-C segments between valve ports and chambers (002 eq. 9–17),
/// rigid pipes or compliant hoses (variant `hose`).
#[derive(Params, Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LineDynamics {
    /// Effect switch.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Structural variant (`pipe` or `hose`).
    #[serde(default)]
    #[param(
        choice,
        desc = "pipe: rigid line (002 eq. 9–17, default); hose: wall compliance added to the oil's \
         and a lumped fitting resistance"
    )]
    pub variant: LineVariant,
    /// Line length per side (m).
    #[param(unit = "m", range = Within(1.0e-3, 1.0e3), desc = "line length per side")]
    pub length: f64,
    /// Inner diameter (m).
    #[param(unit = "m", range = Within(1.0e-4, 0.5), desc = "line inner diameter")]
    pub diameter: f64,
    /// Number of lumped segments per side (-).
    #[param(unit = "-", range = Within(1.0, 200.0), desc = "lumped segments per side")]
    pub segments: u32,
    /// Effective bulk modulus of the line incl. hose wall compliance (Pa); default: fluid β₀.
    #[serde(default)]
    #[param(unit = "Pa", range = Positive, desc = "line effective bulk modulus")]
    pub bulk_modulus: Option<f64>,
    /// Lumped oil volume at the valve-side node of each line (m³), default 0: valve port and
    /// manifold passages, or (001 eq. 14–15) a pumping chamber with its piezo-stack compliance
    /// as an equivalent volume a_p·Δ_gap + β·a_p²/k_p. Compressed with the fluid β₀.
    #[serde(default)]
    #[param(unit = "m³", range = NonNegative, desc = "lumped volume at the valve-side node (default 0)")]
    pub port_volume: f64,
    /// Wall-friction model of the segments (default `steady`, Hagen–Poiseuille only).
    #[serde(default)]
    #[param(
        choice,
        desc = "segment wall friction: steady Hagen–Poiseuille (default), unsteady (Zielke 1968 \
         weighting function, 8 states per segment) or unsteady_trikha (Trikha 1975, 3 states)"
    )]
    pub friction: LineFriction,
    /// Wall compliance of a hose (1/Pa), variant `hose`: 1/β_eff = 1/β + this. Thin wall
    /// D/(t·E) (Merritt 1967 eq. 2-46); 1·10⁻⁹ 1/Pa makes β_eff ≈ 0.6 GPa of a 1.5 GPa oil.
    #[serde(default)]
    #[param(unit = "1/Pa", range = NonNegative, desc = "hose wall compliance ΔV/(V·Δp), e.g. D/(t·E) thin wall (variant hose)")]
    pub wall_compliance: f64,
    /// Laminar resistance of the hose ends and fittings per side (Pa·s/m³), variant `hose`,
    /// added to the segments' Hagen–Poiseuille resistance (spread evenly over them).
    #[serde(default)]
    #[param(unit = "Pa·s/m³", range = NonNegative, desc = "laminar fitting resistance per side, added to the Hagen–Poiseuille one (variant hose)")]
    pub resistance: f64,
}

/// Wall friction of a `line_dynamics` segment (laminar flow).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "snake_case")]
pub enum LineFriction {
    /// Steady Hagen–Poiseuille resistance R = 128μℓ/(πd⁴) with plug-flow inertance ρℓ/A
    /// (002 eq. 9–17).
    #[default]
    Steady,
    /// Frequency-dependent (unsteady) laminar friction: Zielke's (1968) weighting-function
    /// convolution, W(τ) = Σₖ exp(−j²₂,ₖ τ) over the zeros of J₂, with the first two modes
    /// exact and the higher ones lumped per octave of mode number (8 states per segment);
    /// propagation constant within 0.08 % (series impedance within 0.16 %) of the exact
    /// Bessel-function line (001 eq. 6–8) for ω·r²/ν ≤ 3·10⁴. See [`crate::line`].
    Unsteady,
    /// As `unsteady` with Trikha's (1975) three-term fit of W (m = 40, 8.1, 1;
    /// n = 8000, 200, 26.4): cheaper, ≈ 1 % off the exact impedance near ω·r²/ν ≈ 10²–10³.
    UnsteadyTrikha,
}

impl LineFriction {
    /// Config spelling of each model.
    pub const NAMES: &'static [&'static str] = &["steady", "unsteady", "unsteady_trikha"];
}

/// `line_dynamics` as a component: the two line chains, A and B, built alike from the
/// section (`None` without the effect), and whether they are solved whole per substep
/// (`integration.line_method = "implicit"`, [`Setup::implicit_lines`]).
#[derive(Debug, Clone)]
pub struct Lines {
    /// Line A (valve port A → chamber A) and line B.
    chains: Option<(Line, Line)>,
    /// [`LineStage::is_implicit`].
    implicit: bool,
}

impl Component for Lines {
    type Section = LineDynamics;

    /// Cross-field check of the variant: a `hose` fitting resistance is steady, laminar.
    fn validate(section: &LineDynamics) -> Result<(), ConfigError> {
        if section.variant == LineVariant::Hose
            && section.resistance > 0.0
            && section.friction != LineFriction::Steady
        {
            return Err(ConfigError::new(
                "effects.line_dynamics.resistance",
                "a fitting resistance (variant = \"hose\") is laminar and steady; with it use friction = \"steady\" (the unsteady wall-friction terms scale with the wall resistance only)",
            ));
        }
        Ok(())
    }

    fn configure(section: Option<&LineDynamics>, setup: &Setup) -> Self {
        let chains = section.filter(|l| l.enabled).map(|l| {
            let line = || {
                Line::with_fluid(
                    l,
                    setup.density,
                    setup.kinematic_viscosity,
                    setup.bulk_modulus,
                    0.0,
                )
            };
            (line(), line())
        });
        Lines {
            implicit: chains.is_some() && setup.implicit_lines,
            chains,
        }
    }

    /// At rest at 0 Pa gauge; [`LineStage::fill`] then sets the start pressures.
    fn reset(&mut self) {
        self.fill(0.0, 0.0);
    }
}

impl LineStage for Lines {
    #[inline]
    fn is_active(&self) -> bool {
        self.chains.is_some()
    }

    #[inline]
    fn is_implicit(&self) -> bool {
        self.implicit
    }

    fn fill(&mut self, p_a: f64, p_b: f64) {
        if let Some((la, lb)) = self.chains.as_mut() {
            la.fill(p_a);
            lb.fill(p_b);
        }
    }

    fn discretise(&mut self, h: f64) {
        if let Some((la, lb)) = self.chains.as_mut() {
            la.prepare(h);
            lb.prepare(h);
        }
    }

    #[inline]
    fn port_pressures(&self) -> Option<(f64, f64)> {
        self.chains.as_ref().map(|(la, lb)| (la.p[0], lb.p[0]))
    }

    fn fastest_mode(
        &self,
        omega: f64,
        line_scale: f64,
        chamber_cap: f64,
        cbv_caps: [Option<f64>; 2],
    ) -> f64 {
        // Both lines are built alike: line A's modes are line B's.
        let Some((la, _)) = self.chains.as_ref() else {
            return omega;
        };
        let mut omega = omega;
        if self.implicit {
            return omega.max(la.omega_wave());
        }
        omega = omega.max(line_scale * la.omega_max());
        if line_scale < 1.0 {
            // Segment modes held to a stability margin only: the line's own wave modes keep
            // the accuracy rule.
            omega = omega.max(la.omega_wave());
        }
        // Line node coupled to the chamber through the last segment.
        let c_min = la.c.min(chamber_cap);
        omega = omega.max(line_scale * 2.0 / (la.l * c_min).sqrt());
        // Last segment against a counterbalance valve's body volume.
        for c_node in cbv_caps.iter().flatten() {
            omega = omega.max(2.0 / (la.l * c_node.min(la.c)).sqrt());
        }
        omega
    }

    #[inline]
    fn advance_nodes(
        &mut self,
        h: f64,
        q_valve: [f64; 2],
        dq_valve: [f64; 2],
        p_cav: f64,
        p_chamber: [f64; 2],
    ) -> [(f64, f64); 2] {
        let Some((la, lb)) = self.chains.as_mut() else {
            return [(p_chamber[0], 0.0), (p_chamber[1], 0.0)];
        };
        let [qa, qb] = q_valve;
        let [dqa, dqb] = dq_valve;
        let f0a = (qa - la.q[0]) / la.c0;
        let f0b = (qb - lb.q[0]) / lb.c0;
        let p0a = la.p[0] + h * f0a * phi1(dqa / la.c0 * h);
        let p0b = lb.p[0] + h * f0b * phi1(dqb / lb.c0 * h);
        la.advance_interior_nodes(h);
        lb.advance_interior_nodes(h);
        la.p[0] = p0a.max(p_cav);
        lb.p[0] = p0b.max(p_cav);
        for p in la.p.iter_mut().chain(lb.p.iter_mut()) {
            *p = p.max(p_cav);
        }
        [
            (
                *la.p.last().unwrap_or(&p_chamber[0]),
                *la.q.last().unwrap_or(&0.0),
            ),
            (
                *lb.p.last().unwrap_or(&p_chamber[1]),
                *lb.q.last().unwrap_or(&0.0),
            ),
        ]
    }

    #[inline]
    fn advance_flows(&mut self, h: f64, p_end: [f64; 2]) {
        if let Some((la, lb)) = self.chains.as_mut() {
            la.advance_flows(h, p_end[0]);
            lb.advance_flows(h, p_end[1]);
        }
    }

    #[inline]
    fn advance_implicit(
        &mut self,
        h: f64,
        q_valve: [f64; 2],
        dq_valve: [f64; 2],
        ends: [EndNode; 2],
        p_cav: f64,
    ) -> (f64, f64) {
        let Some((la, lb)) = self.chains.as_mut() else {
            return (ends[0].p, ends[1].p);
        };
        let p_a = la
            .advance_implicit(h, q_valve[0], dq_valve[0], ends[0])
            .max(p_cav);
        let p_b = lb
            .advance_implicit(h, q_valve[1], dq_valve[1], ends[1])
            .max(p_cav);
        for p in la.p.iter_mut().chain(lb.p.iter_mut()) {
            *p = p.max(p_cav);
        }
        (p_a, p_b)
    }

    fn state_names(&self, names: &mut Vec<String>) {
        if let Some((la, lb)) = &self.chains {
            for (tag, l) in [("a", la), ("b", lb)] {
                names.extend((0..l.p.len()).map(|i| format!("line_{tag}.p[{i}]")));
                names.extend((0..l.q.len()).map(|i| format!("line_{tag}.q[{i}]")));
                let t = l.terms();
                names.extend(
                    (0..l.y.len()).map(|k| format!("line_{tag}.q[{}].y[{}]", k / t, k % t)),
                );
            }
        }
    }

    fn state(&self, v: &mut Vec<f64>) {
        if let Some((la, lb)) = &self.chains {
            for l in [la, lb] {
                v.extend_from_slice(&l.p);
                v.extend_from_slice(&l.q);
                v.extend_from_slice(&l.y);
            }
        }
    }

    fn set_state(&mut self, next: &mut impl FnMut() -> f64) {
        if let Some((la, lb)) = self.chains.as_mut() {
            for l in [la, lb] {
                for p in l.p.iter_mut() {
                    *p = next();
                }
                for q in l.q.iter_mut() {
                    *q = next();
                }
                for y in l.y.iter_mut() {
                    *y = next();
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sirohi 2003's tube (11.5 in × 1.753 mm, 001), 4 segments, steady friction.
    fn section() -> LineDynamics {
        LineDynamics {
            enabled: true,
            variant: LineVariant::Pipe,
            length: 0.2921,
            diameter: 1.753e-3,
            segments: 4,
            bulk_modulus: None,
            port_volume: 0.0,
            friction: LineFriction::Steady,
            wall_compliance: 0.0,
            resistance: 0.0,
        }
    }

    /// Without the effect (absent or switched off) the stage holds no line: the ports see
    /// the chambers, the substep rule and the log state get nothing from it, and its calls
    /// pass their inputs on. `implicit` alone does not make a chain.
    #[test]
    fn stage_without_the_effect_passes_everything_on() {
        let mut off = section();
        off.enabled = false;
        let setup = Setup {
            implicit_lines: true,
            ..Setup::TEST
        };
        for s in [None, Some(&off)] {
            let mut st = Lines::configure(s, &setup);
            assert!(!st.is_active() && !st.is_implicit());
            assert_eq!(st.port_pressures(), None);
            assert_eq!(
                st.fastest_mode(123.0, 1.0, 1e-12, [Some(1e-13), None]),
                123.0
            );
            let ends = st.advance_nodes(1e-5, [1e-4, -1e-4], [-1e-9, -1e-9], -0.95e5, [2e6, 1e6]);
            assert_eq!(ends, [(2e6, 0.0), (1e6, 0.0)]);
            let end = EndNode {
                p: 3e6,
                cap: 1e-12,
                flow: 0.0,
                dflow: 0.0,
            };
            let end_b = EndNode { p: 4e6, ..end };
            assert_eq!(
                st.advance_implicit(1e-5, [1e-4, 0.0], [0.0; 2], [end, end_b], -0.95e5),
                (3e6, 4e6)
            );
            let (mut names, mut v) = (Vec::new(), Vec::new());
            st.state_names(&mut names);
            st.state(&mut v);
            assert!(names.is_empty() && v.is_empty());
        }
    }

    /// With the effect: two equal chains, filled at the chambers' pressures by `fill`, back
    /// at rest after `reset`, their state named and laid out node pressures, segment flows,
    /// convolution states, line A before line B.
    #[test]
    fn stage_holds_two_chains_that_fill_reset_and_round_trip_their_state() {
        let mut s = section();
        s.friction = LineFriction::UnsteadyTrikha;
        let mut st = Lines::configure(Some(&s), &Setup::TEST);
        assert!(st.is_active() && !st.is_implicit());
        st.fill(2e6, 1e6);
        assert_eq!(st.port_pressures(), Some((2e6, 1e6)));
        let mut names = Vec::new();
        st.state_names(&mut names);
        // Per line 4 nodes, 4 segment flows and 4 × 3 Trikha states.
        assert_eq!(names.len(), 2 * (4 + 4 + 12));
        assert_eq!(names[0], "line_a.p[0]");
        assert_eq!(names[4], "line_a.q[0]");
        assert_eq!(names[8], "line_a.q[0].y[0]");
        assert_eq!(names[19], "line_a.q[3].y[2]");
        assert_eq!(names[20], "line_b.p[0]");
        let mut v = Vec::new();
        st.state(&mut v);
        assert_eq!(v.len(), names.len());
        assert!(v[..4].iter().all(|&p| p == 2e6) && v[20..24].iter().all(|&p| p == 1e6));
        let mut k = 0.0;
        st.set_state(&mut || {
            k += 1.0;
            k
        });
        let mut w = Vec::new();
        st.state(&mut w);
        assert_eq!(w, (1..=names.len()).map(|i| i as f64).collect::<Vec<_>>());
        st.reset();
        let mut r = Vec::new();
        st.state(&mut r);
        assert!(r.iter().all(|&x| x == 0.0));
        let implicit = Lines::configure(
            Some(&s),
            &Setup {
                implicit_lines: true,
                ..Setup::TEST
            },
        );
        assert!(implicit.is_implicit());
    }

    /// The substep rule: the implicit chain adds its half-wave mode only; the symplectic one
    /// its segment mode, its end against the chamber and a counterbalance valve's node.
    #[test]
    fn fastest_mode_of_each_scheme() {
        let s = section();
        let sym = Lines::configure(Some(&s), &Setup::TEST);
        let imp = Lines::configure(
            Some(&s),
            &Setup {
                implicit_lines: true,
                ..Setup::TEST
            },
        );
        let (la, _) = sym.chains.as_ref().unwrap();
        assert_eq!(imp.fastest_mode(0.0, 1.0, 1.0, [None; 2]), la.omega_wave());
        // A huge chamber: the segment mode sets it.
        let seg = sym.fastest_mode(0.0, 1.0, 1.0, [None; 2]);
        assert_eq!(seg, la.omega_max().max(2.0 / (la.l * la.c).sqrt()));
        // A counterbalance valve node far stiffer than a segment node raises it.
        let c_node = la.c * 1e-4;
        let cbv = sym.fastest_mode(0.0, 1.0, 1.0, [Some(c_node), None]);
        assert_eq!(cbv, seg.max(2.0 / (la.l * c_node).sqrt()));
        assert!(cbv > seg);
        // Above every line mode, ω passes.
        assert_eq!(sym.fastest_mode(1e12, 1.0, 1.0, [None; 2]), 1e12);
    }

    /// The component's check: a hose fitting resistance with unsteady friction is refused,
    /// naming the parameter; steady is fine.
    #[test]
    fn validate_refuses_a_fitting_resistance_with_unsteady_friction() {
        let mut s = section();
        s.variant = LineVariant::Hose;
        s.resistance = 1e9;
        assert!(Lines::validate(&s).is_ok());
        s.friction = LineFriction::Unsteady;
        let e = Lines::validate(&s).unwrap_err();
        assert!(
            e.to_string().contains("effects.line_dynamics.resistance"),
            "{e}"
        );
        s.variant = LineVariant::Pipe;
        assert!(Lines::validate(&s).is_ok());
    }
}
