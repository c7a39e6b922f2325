//! Numerical linearisation of the plant around an operating point.
//!
//! Discrete time: the plant's own step map over one control period with the command held
//! (zero-order hold), x⁺ = Φ(x, u), differentiated by central differences: A = ∂Φ/∂x,
//! B = ∂Φ/∂u. This is the exact sampled-data model of the simulated plant, substeps and all,
//! so the loop analysis includes the sample and hold. Continuous time: the same map over a
//! tiny step h (one substep), A_c ≈ (∂Φ_h/∂x − I)/h, for comparison with the papers'
//! continuous analyses.

use crate::oppoint::OperatingPoint;
use crate::AnalysisError;
use ehactl_plant::exact::balancing_scales;
use ehactl_plant::Plant;
use nalgebra::{Complex, DMatrix, DVector};

/// A linear state-space model y = C·x, x⁺ = A·x + B·u (discrete) or ẋ = A·x + B·u.
#[derive(Debug, Clone)]
pub struct LinearModel {
    /// State names (see `Plant::linear_state_names`).
    pub names: Vec<String>,
    /// State matrix.
    pub a: DMatrix<f64>,
    /// Input vector (per V of valve command).
    pub b: DVector<f64>,
    /// Output rows: load-cell force (N) and piston position (m).
    pub c_force: DVector<f64>,
    /// Position output row.
    pub c_position: DVector<f64>,
    /// Sample period (s) for a discrete model, None for continuous.
    pub dt: Option<f64>,
    /// State scaling of the balanced realisation: model state i = physical state i / `scale[i]`.
    pub scale: Vec<f64>,
}

/// Output channel of a linear model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Output {
    /// Rod force seen by the load cell (N).
    Force,
    /// Piston position (m).
    Position,
}

fn scales(names: &[String], plant: &Plant) -> Vec<f64> {
    let p = plant.params();
    let ps = p.supply.pressure.max(1e5);
    let area = p.cylinder.area_a.max(p.cylinder.area_b);
    names
        .iter()
        .map(|n| {
            if n.starts_with("spool") {
                1e-6
            } else if n.starts_with('p') || n.contains(".p[") {
                1e-7 * ps
            } else if n.contains(".q[") {
                1e-10 * area / 1e-4
            } else if n.starts_with('x') {
                1e-9 * p.cylinder.stroke.max(1e-3)
            } else {
                1e-7
            }
        })
        .collect()
}

fn outputs(plant: &Plant) -> (f64, f64) {
    let s = plant.state();
    (s.rod_force, s.x)
}

/// Linearise the map of `plant` (at rest at `op`) over one step of its control period with
/// the command `u0` held.
fn jacobian(plant: &Plant, u0: f64, du: f64) -> Result<LinearModel, AnalysisError> {
    let names = plant.linear_state_names();
    let x0 = plant.linear_state();
    let n = x0.len();
    let h = scales(&names, plant);
    let step = |x: &[f64], u: f64| -> Result<Vec<f64>, AnalysisError> {
        let mut p = plant.clone();
        p.set_linear_state(x);
        p.step(u)
            .map_err(|e| AnalysisError::Numerical(format!("linearisation: {e}")))?;
        Ok(p.linear_state())
    };
    let mut a = DMatrix::zeros(n, n);
    let mut c_force = DVector::zeros(n);
    let mut c_position = DVector::zeros(n);
    for j in 0..n {
        let mut xp = x0.clone();
        let mut xm = x0.clone();
        xp[j] += h[j];
        xm[j] -= h[j];
        let fp = step(&xp, u0)?;
        let fm = step(&xm, u0)?;
        for i in 0..n {
            a[(i, j)] = (fp[i] - fm[i]) / (2.0 * h[j]);
        }
        let mut pp = plant.clone();
        pp.set_linear_state(&xp);
        let (fp_f, fp_x) = outputs(&pp);
        let mut pm = plant.clone();
        pm.set_linear_state(&xm);
        let (fm_f, fm_x) = outputs(&pm);
        c_force[j] = (fp_f - fm_f) / (2.0 * h[j]);
        c_position[j] = (fp_x - fm_x) / (2.0 * h[j]);
    }
    let fp = step(&x0, u0 + du)?;
    let fm = step(&x0, u0 - du)?;
    let b = DVector::from_iterator(n, (0..n).map(|i| (fp[i] - fm[i]) / (2.0 * du)));
    let mut m = LinearModel {
        names,
        a,
        b,
        c_force,
        c_position,
        dt: Some(plant.control_dt()),
        scale: vec![1.0; n],
    };
    m.balance();
    Ok(m)
}

/// Discrete-time model over one control period (zero-order hold on the command).
pub fn discrete(op: &OperatingPoint) -> Result<LinearModel, AnalysisError> {
    let fs = op.plant.params().valve.command_full_scale;
    jacobian(&op.plant, op.u0, 1e-6 * fs)
}

/// Continuous-time model from the map over one tiny step `h` (s), e.g. 1e-7.
pub fn continuous(op: &OperatingPoint, h: f64) -> Result<LinearModel, AnalysisError> {
    let mut params = op.plant.params().clone();
    params.integration.substeps = 1;
    let mut tiny = Plant::configure(&params, h)?;
    tiny.set_linear_state(&op.plant.linear_state());
    // Settle the valve state consistent with the held command: one tiny step.
    let fs = params.valve.command_full_scale;
    let mut m = jacobian(&tiny, op.u0, 1e-6 * fs)?;
    let n = m.a.nrows();
    // Balancing is a similarity transform, so A_d − I stays (A_c·h) in the balanced basis.
    m.a = (m.a - DMatrix::identity(n, n)) / h;
    m.b /= h;
    m.dt = None;
    Ok(m)
}

impl LinearModel {
    /// Balance the realisation (Parlett–Reinsch: scale states by powers of 2 until every
    /// row and column of A has comparable norm). Pressures in Pa next to positions in m make
    /// A span 20 decades; balancing keeps eigenvalues and (zI − A)⁻¹ accurate. The transfer
    /// function is unchanged: A' = D⁻¹AD, B' = D⁻¹B, C' = CD.
    fn balance(&mut self) {
        let n = self.a.nrows();
        let mut d = vec![1.0f64; n];
        balancing_scales(&mut d, |i, j| self.a[(i, j)], 100);
        for i in 0..n {
            for j in 0..n {
                self.a[(i, j)] *= d[j] / d[i];
            }
            self.b[i] /= d[i];
            self.c_force[i] *= d[i];
            self.c_position[i] *= d[i];
        }
        for (s, di) in self.scale.iter_mut().zip(d) {
            *s *= di;
        }
    }

    /// Output row for a channel.
    pub fn c(&self, out: Output) -> &DVector<f64> {
        match out {
            Output::Force => &self.c_force,
            Output::Position => &self.c_position,
        }
    }

    /// The complex frequency variable at `f_hz`: z = e^(jωT) (discrete) or s = jω.
    pub fn frequency_variable(&self, f_hz: f64) -> Complex<f64> {
        let w = std::f64::consts::TAU * f_hz;
        match self.dt {
            Some(t) => Complex::from_polar(1.0, w * t),
            None => Complex::new(0.0, w),
        }
    }

    /// Transfer function output/command at `f_hz` (N/V or m/V): C·(zI − A)⁻¹·B.
    pub fn response(&self, out: Output, f_hz: f64) -> Complex<f64> {
        let n = self.a.nrows();
        let z = self.frequency_variable(f_hz);
        let mut m: DMatrix<Complex<f64>> = self.a.map(|v| Complex::new(-v, 0.0));
        for i in 0..n {
            m[(i, i)] += z;
        }
        let rhs: DVector<Complex<f64>> = self.b.map(|v| Complex::new(v, 0.0));
        let x = match m.lu().solve(&rhs) {
            Some(x) => x,
            None => return Complex::new(f64::INFINITY, 0.0),
        };
        let c = self.c(out);
        (0..n).map(|i| x[i] * c[i]).sum()
    }

    /// Eigenvalues of A (discrete: z-plane; continuous: rad/s).
    pub fn eigenvalues(&self) -> Vec<Complex<f64>> {
        self.a.complex_eigenvalues().iter().copied().collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ehactl_plant::PlantParams;

    /// A closed critical-centre valve on a double-ended cylinder at mid-stroke, mass m: the
    /// piston mode is ω² = k/m with the oil column k_h = β·A²·(1/V_a + 1/V_b) (Merritt 1967,
    /// eq. 5-53 with zero flow-pressure coefficient). A Dahl term F_d·z on the rod adds its
    /// pre-yield stiffness F_d/δ at rest (dz/dx = 1/δ at z = 0, Dahl 1968), so the
    /// linearisation must carry the state z: ω² = (k_h + F_d/δ)/m.
    #[test]
    fn dahl_pre_yield_stiffness_enters_the_piston_mode() {
        let (area, v0, beta, m): (f64, f64, f64, f64) = (7.0e-4, 1.0e-4, 1.4e9, 10.0);
        let (fd, delta) = (800.0, 1e-4);
        let mode = |dahl: f64| -> f64 {
            let toml = format!(
                r#"
                [fluid]
                density = 870.0
                bulk_modulus = {beta}
                [supply]
                pressure = 21.0e6
                [valve]
                command_full_scale = 10.0
                flow_form = "kq"
                rated_flow = 5.4e-5
                rated_pressure_drop = 1.0e6
                [cylinder]
                area_a = {area}
                area_b = {area}
                dead_volume_a = {v0}
                dead_volume_b = {v0}
                stroke = 0.1
                initial_position = 0.05
                [mechanics]
                mass = {m}
                end_stops = false
                [effects.polynomial_force]
                dahl = {dahl}
                dahl_travel = {delta}
                "#
            );
            let p: PlantParams = toml::from_str(&toml).unwrap();
            let mut plant = Plant::configure(&p, 1e-3).unwrap();
            plant.initialize();
            let op = OperatingPoint {
                plant,
                u0: 0.0,
                reference: 0.0,
                feedback: 0.0,
                settled: true,
                time_s: 0.0,
            };
            let lm = continuous(&op, 1e-7).unwrap();
            lm.eigenvalues()
                .iter()
                .map(|e| e.norm())
                .fold(0.0, f64::max)
        };
        let v = v0 + area * 0.05;
        let kh = beta * area * area * 2.0 / v;
        let without = mode(0.0);
        let with = mode(fd);
        let want0 = (kh / m).sqrt();
        let want = ((kh + fd / delta) / m).sqrt();
        assert!((without / want0 - 1.0).abs() < 0.01, "{without} vs {want0}");
        assert!(
            (with / want - 1.0).abs() < 0.01,
            "{with} vs {want} (k_h/m alone: {want0})"
        );
    }
}
