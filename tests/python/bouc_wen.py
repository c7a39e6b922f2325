"""An MR damper test campaign written from the published equations, independent of ehactl's
plant: the modified Bouc–Wen model of Spencer, Dyke, Sain & Carlson, "Phenomenological model
for magnetorheological dampers", J. Eng. Mech. 123(3):230–238, 1997, eqs. (5)–(9), with the
parameters of its Table 1 converted to SI, and the coil input u (here the current in A, held
constant through each test as in a characterisation campaign) entering α, c₀ and c₁ affinely
(eqs. 10–12):

    F  = c₁·ẏ + k₁·(x − x₀)
    ẏ  = [α·z + c₀·ẋ + k₀·(x − y)] / (c₀ + c₁)
    ż  = −γ·|ẋ − ẏ|·z·|z|ⁿ⁻¹ − β·(ẋ − ẏ)·|z|ⁿ + A·(ẋ − ẏ)
    α = α_a + α_b·u,  c₁ = c₁a + c₁b·u,  c₀ = c₀a + c₀b·u

The imposed displacement x(t) (sines of several amplitudes and frequencies, a band-limited
random history) is known in closed form, so ẋ is exact; the two states (y, z) are integrated by
SciPy's LSODA (adaptive, stiff-aware) at tight tolerances, and the force is sampled at the
record's rate with white load-cell noise. Nothing here comes from ehactl's code."""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

# Spencer et al. 1997, Table 1 (cm → m): N·s/m, N/m, m, m⁻², -.
C0A, C0B = 21.0e2, 3.50e2
K0 = 46.9e2
C1A, C1B = 283.0e2, 2.95e2
K1 = 5.00e2
X0 = 14.3e-2
ALPHA_A, ALPHA_B = 140.0e2, 695.0e2
GAMMA = BETA = 363.0e4
A_BW = 301.0
N_BW = 2


def coil(current: float, saturation: float | None = None) -> float:
    """The coil input the coefficients are affine in: the current itself (A), or with a
    magnetic `saturation` scale i_s (A) the saturating (1 − e^(−i/i_s)) / (1 − e^(−1/i_s)),
    equal to the current at 0 and 1 A and bending between; a negative `saturation` −i_k (A)
    is a hard knee instead: min(i, i_k)/i_k … rising linearly to full at i_k and flat beyond
    (a coil driven into saturation by its amplifier's current limit)."""
    if saturation is None:
        return current
    if saturation < 0:
        return min(current, -saturation) / -saturation
    return (1.0 - np.exp(-current / saturation)) / (1.0 - np.exp(-1.0 / saturation))


def coefficients(current: float, saturation: float | None = None) -> tuple[float, float, float]:
    """α (N/m), c₀ (N·s/m), c₁ (N·s/m) at the coil input `current` (A, as the paper's V)."""
    u = coil(current, saturation)
    return ALPHA_A + ALPHA_B * u, C0A + C0B * u, C1A + C1B * u


def force(t: np.ndarray, x, v, current: float, saturation: float | None = None) -> np.ndarray:
    """Damper force (N) at times `t` (s) for the displacement x(t) (m) and velocity v(t) (m/s),
    given as functions of time, at a constant `current` (A); `saturation`: see :func:`coil`."""
    alpha, c0, c1 = coefficients(current, saturation)

    def rhs(tt, s):
        y, z = s
        xd = v(tt)
        yd = (alpha * z + c0 * xd + K0 * (x(tt) - y)) / (c0 + c1)
        r = xd - yd
        zd = -GAMMA * abs(r) * z * abs(z) ** (N_BW - 1) - BETA * r * abs(z) ** N_BW + A_BW * r
        return [yd, zd]

    sol = solve_ivp(rhs, (t[0], t[-1]), [x(t[0]), 0.0], method="LSODA", t_eval=t,
                    rtol=1e-8, atol=[1e-10, 1e-10], max_step=float(t[1] - t[0]))
    if not sol.success:
        raise RuntimeError(sol.message)
    y, z = sol.y
    xs = np.array([x(tt) for tt in t])
    yd = (alpha * z + c0 * np.array([v(tt) for tt in t]) + K0 * (xs - y)) / (c0 + c1)
    return c1 * yd + K1 * (xs - X0)


def sine(amplitude: float, freq: float):
    """x(t) = a·sin(2πft) about mid stroke, and its exact velocity (m, m/s)."""
    w = 2 * np.pi * freq
    return (lambda t: amplitude * np.sin(w * t)), (lambda t: amplitude * w * np.cos(w * t))


def random_history(seed: int, rms: float, f_max: float, duration: float):
    """A band-limited random displacement (sum of 40 sines of random phase between 0.1 Hz and
    `f_max`, scaled to `rms` m) and its exact velocity: a stand-in for a recorded history."""
    rng = np.random.default_rng(seed)
    f = np.linspace(0.1, f_max, 40)
    ph = rng.uniform(0, 2 * np.pi, f.size)
    amp = 1.0 / np.sqrt(f)
    amp *= rms / np.sqrt(0.5 * np.sum(amp ** 2))
    w = 2 * np.pi * f
    return (lambda t: float(np.sum(amp * np.sin(w * t + ph))),
            lambda t: float(np.sum(amp * w * np.cos(w * t + ph))))


def record(motion, current: float, duration: float, rate: float = 1000.0,
           noise: float = 2.0, seed: int = 0, saturation: float | None = None) -> dict[str, np.ndarray]:
    """One motion-only test: columns t (s), x (m), force (N, with `noise` N rms white load-cell
    noise), current (A); `saturation`: the coil's, see :func:`coil`."""
    x, v = motion
    t = np.arange(int(round(duration * rate))) / rate
    f = force(t, x, v, current, saturation)
    rng = np.random.default_rng(seed)
    return {
        "t": t,
        "x": np.array([x(tt) for tt in t]),
        "force": f + noise * rng.standard_normal(t.size),
        "current": np.full(t.size, current),
    }


def write_csv(path, rec: dict[str, np.ndarray]) -> None:
    cols = list(rec)
    np.savetxt(path, np.column_stack([rec[c] for c in cols]), delimiter=",",
               header=",".join(cols), comments="", fmt="%.10g")
