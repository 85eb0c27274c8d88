"""The calibrated misspecification test and the localisation, on synthetic residuals."""

import numpy as np

from vdsbi.diagnostics import locate_mismatch, misspecification_test

RATE = 200.0


def _fitted_noise(rng, L=800, C=2, K=3):
    """White noise with K smooth directions fitted out (what a least-squares fit leaves)."""
    t = np.arange(L) / RATE
    basis = np.stack([np.ones(L), t, np.sin(2 * np.pi * 0.4 * t)], -1)[:, :K]
    jac = np.zeros((L * C, K * C))
    for c in range(C):
        jac[c::C, c * K : (c + 1) * K] = basis
    eps = rng.standard_normal(L * C)
    q, _ = np.linalg.qr(jac)
    res = eps - q @ (q.T @ eps)
    return res.reshape(1, L, C), jac


def test_false_alarm_rate_is_calibrated():
    rng = np.random.default_rng(0)
    rejections = 0
    n = 40
    for i in range(n):
        res, jac = _fitted_noise(rng)
        out = misspecification_test(i, res, jac, rate=RATE, channels=("a", "b"), num_draws=200)
        rejections += out.p_value < 0.05
    # Binomial(40, 0.05): P(X > 6) < 1.5 %.
    assert rejections <= 6


def test_detects_slow_structure_and_locates_it():
    rng = np.random.default_rng(1)
    res, jac = _fitted_noise(rng)
    t = np.arange(res.shape[1]) / RATE
    res[0, :, 1] += 0.5 * np.sin(2 * np.pi * 0.25 * t + 1.0)
    out = misspecification_test(0, res, jac, rate=RATE, channels=("a", "b"), num_draws=200)
    assert out.p_value < 0.01
    times = t[None]
    inputs = rng.standard_normal((1, res.shape[1], 3))
    loc = locate_mismatch(out, res, times, inputs, rate=RATE)
    assert loc.channels == ["b"]
    assert [0.0, 0.5] in loc.bands_hz


def test_statistic_ignores_noise_scale():
    rng = np.random.default_rng(2)
    res, jac = _fitted_noise(rng)
    a = misspecification_test(3, res, jac, rate=RATE, channels=("a", "b"), num_draws=100)
    b = misspecification_test(3, 3.0 * res, jac, rate=RATE, channels=("a", "b"), num_draws=100)
    assert np.isclose(a.statistic, b.statistic) and a.p_value == b.p_value


def test_cross_correlation_finds_the_lag():
    rng = np.random.default_rng(3)
    L = 2000
    u = np.convolve(rng.standard_normal(L + 200), np.ones(20) / 20, "same")
    lag = 40  # 0.2 s
    r = 3.0 * u[200 - lag : 200 - lag + L] + 0.1 * rng.standard_normal(L)
    res = r.reshape(1, L, 1)
    inputs = np.stack([u[200 : 200 + L]] * 3, -1)[None]
    out = misspecification_test(0, res, None, rate=RATE, channels=("yaw_rate",), num_draws=50)
    loc = locate_mismatch(out, res, (np.arange(L) / RATE)[None], inputs, rate=RATE)
    x = loc.xcorr["yaw_rate"]["steer"]
    assert x["significant"] and abs(x["lag_s"] - 0.2) < 0.011
