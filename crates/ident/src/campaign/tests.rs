use super::*;

/// The least-squares derivative is exact on a quadratic (central window) and on a line.
#[test]
fn derivative_is_exact_on_polynomials() {
    let dt = 0.01;
    let x: Vec<f64> = (0..50).map(|k| 3.0 + 2.0 * (k as f64 * dt)).collect();
    for m in [1, 2, 4] {
        for v in derivative(&x, dt, m) {
            assert!((v - 2.0).abs() < 1e-9);
        }
    }
    let q: Vec<f64> = (0..50).map(|k| (k as f64 * dt).powi(2)).collect();
    let v = derivative(&q, dt, 3);
    for (k, vk) in v.iter().enumerate().take(47).skip(3) {
        assert!((vk - 2.0 * k as f64 * dt).abs() < 1e-9, "{k}");
    }
}
