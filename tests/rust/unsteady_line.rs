//! Unsteady (frequency-dependent) laminar friction of the plant's lumped line
//! (`effects.line_dynamics.friction = "unsteady"`, Zielke 1968 weighting function, see
//! crates/plant/src/line.rs) against the exact Bessel-function line impedance of seed 001
//! eq. 6–8 (crates/analysis/src/tline.rs, `Friction::Bessel`).
//!
//! One segment of a long tube (1 m, 1.75 mm bore: 001's tube) is driven in the time domain by
//! the real `Line::advance_flows` with a sinusoidal pressure difference; its series impedance
//! P/Q per metre, demodulated from the steady-state response, must equal the exact laminar
//! impedance Z = (ρs/A)/(1 − B_r) at 2, 20 and 200 cSt, including ω/ω_v ≈ 100.

use ehactl_analysis::tline::{
    bessel_ratio, bessel_ratio_exact, viscous_frequency, Friction, LineSection, SIROHI_TUBE_ID,
};
use ehactl_config::RigConfig;
use ehactl_plant::line::Line;
use ehactl_plant::params::{Fluid, LineDynamics, LineFriction};
use ehactl_plant::Plant;
use ehactl_tests::{allocations, CountingAlloc};
use nalgebra::Complex;
use std::f64::consts::{PI, TAU};

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

fn circuit_text() -> String {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../configs/sirohi2003_circuit.toml"
    );
    std::fs::read_to_string(path).expect("config")
}

type C64 = Complex<f64>;
const CST: f64 = 1e-6;

fn fluid(nu: f64) -> Fluid {
    Fluid {
        density: 859.0,
        bulk_modulus: 1.7926e9,
        kinematic_viscosity: nu,
        cavitation_pressure: -0.95e5,
    }
}

/// Series impedance (Pa·s/m³) of a 1 m single-segment line at `f_hz`, from its time-domain
/// response to p(t) = 1e5·sin(ωt) Pa across it (substep `h`, s).
fn simulated_impedance(friction: LineFriction, nu: f64, f_hz: f64, h: f64) -> C64 {
    let cfg = LineDynamics {
        enabled: true,
        length: 1.0,
        diameter: SIROHI_TUBE_ID,
        segments: 1,
        bulk_modulus: None,
        port_volume: 0.0,
        friction,
    };
    let fl = fluid(nu);
    let mut line = Line::new(&cfg, &fl, 0.0);
    line.prepare(h);
    let w = TAU * f_hz;
    let r = 0.5 * SIROHI_TUBE_ID;
    // Settle: 12 slowest time constants (R/L and the first Zielke mode, ≥ 26·ν/r²).
    let slow = (8.0 * nu / (r * r)).min(26.3 * nu / (r * r));
    let periods = 20.0;
    let t_settle = (12.0 / slow / (1.0 / f_hz)).ceil() / f_hz;
    let n_settle = (t_settle / h).round() as usize;
    let n_window = (periods / f_hz / h).round() as usize;
    let amp = 1e5;
    let (mut qs, mut qc) = (0.0, 0.0);
    for k in 0..n_settle + n_window {
        let t = (k + 1) as f64 * h;
        line.p[0] = amp * (w * t).sin();
        line.advance_flows(h, 0.0);
        if k >= n_settle {
            // Flows are on the half-step grid of the symplectic pair: sample at t − h/2.
            let tq = t - 0.5 * h;
            qs += line.q[0] * (w * tq).sin();
            qc += line.q[0] * (w * tq).cos();
        }
    }
    let q = C64::new(qs, qc) * (2.0 / n_window as f64); // complex amplitude, sin ↔ 1
    C64::new(amp, 0.0) / q
}

/// Exact laminar series impedance per metre (Pa·s/m⁴), 001 eq. 6–8 with the Bessel B_r.
fn exact_impedance(nu: f64, f_hz: f64, woods: bool) -> C64 {
    let fl = fluid(nu);
    let area = 0.25 * PI * SIROHI_TUBE_ID * SIROHI_TUBE_ID;
    let s = C64::new(0.0, TAU * f_hz);
    let wv = viscous_frequency(nu, SIROHI_TUBE_ID);
    let b = if woods {
        bessel_ratio(s, wv)
    } else {
        bessel_ratio_exact(s, wv)
    };
    s * (fl.density / area) / (C64::new(1.0, 0.0) - b)
}

#[test]
fn unsteady_segment_impedance_matches_the_bessel_line() {
    // tline's Bessel line agrees with the same impedance: Γ·Z_c = Z·l (a check of the helper).
    let sec = LineSection::tube(1.0, SIROHI_TUBE_ID);
    let tl = ehactl_analysis::tline::Fluid {
        density: 859.0,
        bulk_modulus: 1.7926e9,
        kinematic_viscosity: 2.0 * CST,
    };
    let s = C64::new(0.0, TAU * 350.0);
    let (g, zc) = sec.gamma_zc(&tl, Friction::Bessel, s);
    assert!(((g * zc) / exact_impedance(2.0 * CST, 350.0, false) - 1.0).norm() < 1e-12);

    let h = 1e-7;
    for nu_cst in [2.0, 20.0, 200.0] {
        let nu = nu_cst * CST;
        let wv = viscous_frequency(nu, SIROHI_TUBE_ID);
        for f in [50.0, 350.0, 1000.0] {
            let z = exact_impedance(nu, f, false);
            let zw = exact_impedance(nu, f, true);
            let rel = |m: LineFriction| (simulated_impedance(m, nu, f, h) / z - 1.0).norm();
            let (e_u, e_t, e_s) = (
                rel(LineFriction::Unsteady),
                rel(LineFriction::UnsteadyTrikha),
                rel(LineFriction::Steady),
            );
            println!(
                "{nu_cst:>5} cSt {f:>6} Hz ω/ω_v {:7.1}: |Z/Z_Bessel − 1| unsteady {:.2e}, \
                 Trikha {:.2e}, steady {:.2e}; Woods (tline Dissipative) vs Bessel {:.2e}",
                TAU * f / wv,
                e_u,
                e_t,
                e_s,
                (zw / z - 1.0).norm()
            );
            // Model error ≤ 1.5e-3 in Z (≤ 0.08 % in √Z, line.rs) + time step ωh/2 ≤ 3.2e-4.
            assert!(e_u < 2e-3, "{nu_cst} cSt {f} Hz: {e_u}");
            // The test can fail: steady friction misses the boundary-layer impedance.
            assert!(
                e_s > 10.0 * e_u,
                "{nu_cst} cSt {f} Hz: steady {e_s} vs {e_u}"
            );
        }
    }
}

#[test]
fn unsteady_line_steps_without_allocating_and_stays_finite() {
    let cfg = RigConfig::from_toml_str(&circuit_text()).expect("config");
    let line = cfg.plant.effects.line_dynamics.as_ref().unwrap();
    assert_eq!(line.friction, LineFriction::Unsteady);
    let mut plant = Plant::configure(&cfg.plant, cfg.timebase().period()).expect("plant");
    let n = plant.linear_state().len();
    let names = plant.linear_state_names();
    assert_eq!(names.len(), n);
    // 2 lines × segments × (p, q and 8 convolution states) + p_a, p_b, x, v.
    assert_eq!(n, 2 * line.segments as usize * 10 + 4, "{names:?}");
    assert!(names.iter().any(|s| s == "line_a.q[0].y[7]"));
    plant.step(1.0).unwrap();
    let before = allocations();
    for k in 0..500 {
        let u = (k as f64 * 0.3).sin();
        plant.step(u).unwrap();
    }
    let n_allocs = allocations() - before;
    assert_eq!(n_allocs, 0, "allocations in 500 plant steps");
    // The counter works on this thread.
    let v: Vec<u8> = Vec::with_capacity(8);
    assert!(allocations() > before && v.capacity() >= 8);
    assert!(plant.linear_state().iter().all(|v| v.is_finite()));
    // set_linear_state ∘ linear_state is the identity, convolution states included.
    let mut x = plant.linear_state();
    x[n - 1] += 1e-9;
    plant.set_linear_state(&x);
    assert_eq!(plant.linear_state(), x);
}

#[test]
fn bad_friction_model_is_a_clear_config_error() {
    let text = circuit_text().replace("friction = \"unsteady\"", "friction = \"turbulent\"");
    assert!(text.contains("turbulent"));
    let err = RigConfig::from_toml_str(&text).expect_err("must be refused");
    let msg = err.to_string();
    println!("{msg}");
    assert_eq!(err.path, "effects.line_dynamics.friction", "{msg}");
    assert!(
        msg.contains("\"unsteady\"") && msg.contains("turbulent"),
        "{msg}"
    );
    assert!(!msg.contains('\n'), "{msg}");
}

#[test]
fn stiff_convolution_terms_do_not_limit_the_substep() {
    // 200 cSt: the fastest term decays at aᵢ = nᵢ·ν/r² ≈ 2.2e7 1/s (n = 83 234; Trikha's
    // n = 8000: 2.1e6 1/s), i.e. aᵢ·h up to ≈ 430 at h = 20 µs. Exact integration keeps it stable and accurate:
    // the error is first order in h only and halves with h.
    let nu = 200.0 * CST;
    let f = 50.0;
    let z = exact_impedance(nu, f, false);
    for model in [LineFriction::Unsteady, LineFriction::UnsteadyTrikha] {
        let errs: Vec<f64> = [2e-5, 1e-5, 5e-6]
            .iter()
            .map(|&h| (simulated_impedance(model, nu, f, h) / z - 1.0).norm())
            .collect();
        println!("{model:?} 200 cSt 50 Hz, h = 20/10/5 µs: |Z/Z_Bessel − 1| = {errs:?}");
        assert!(errs.iter().all(|e| e.is_finite() && *e < 0.02), "{errs:?}");
        // Model error at this point is < 1e-4 (unsteady) / 7e-5 (Trikha), see above.
        assert!(
            errs[1] < 0.6 * errs[0] && errs[2] < 0.6 * errs[1],
            "{errs:?}"
        );
    }
}
