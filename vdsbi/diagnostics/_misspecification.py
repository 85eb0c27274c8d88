"""A calibrated misspecification test on fitted residuals, and where the mismatch sits.

Setting: a model was fitted to a recording by least squares (or MAP) under additive white
Gaussian sensor noise of known std per channel; `residuals` are the whitened residuals
(measured − predicted)/σ on the fitted samples, `jacobian` their derivative with respect to the
fitted parameters at the optimum.

Test statistic. Physics left out of a model shows as slow, structured residuals; white sensor
noise is flat in frequency. For each channel c and low band b (default 0–0.5, 0.5–2, 2–5 Hz)
S_cb = log(mean periodogram in b / mean periodogram in the reference band 10 Hz–0.8·Nyquist).
The ratio makes S independent of the noise level, so a mis-stated σ does not raise false
alarms. T = max over (c, b) of S_cb standardised by its null mean and std.

Null distribution, by simulation. Under the well-specified model the fitted residual is, to
first order, (I − H)ε with ε ~ N(0, I) in whitened units and H the hat matrix of the Jacobian
(the fit absorbs part of the noise, mostly at low frequency). `num_draws` such residuals are
simulated, T is computed on each, and p = (1 + #{T* ≥ T}) / (1 + num_draws). This is a
parametric bootstrap of the noise with the refit linearised; it accounts for the fit, and the
multiple (c, b) comparisons are covered by taking the max.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from scipy import stats

#: Default low-frequency bands, Hz, where missing physics shows.
DEFAULT_BANDS: tuple[tuple[float, float], ...] = ((0.0, 0.5), (0.5, 2.0), (2.0, 5.0))
#: Reference band, Hz (upper end None: 0.8·Nyquist).
REFERENCE_BAND: tuple[float, float | None] = (10.0, None)


@dataclasses.dataclass
class MisspecificationTest:
    """Result of `misspecification_test`.

    Attributes:
        p_value: calibrated p-value of the max statistic.
        statistic: observed T.
        z_scores: (C, B) standardised band statistics per channel and band.
        band_p: (C, B) per-cell p-values from the same simulated null (not multiplicity
            corrected).
        band_power_ratio: (C, B) observed mean band power / mean reference-band power,
            divided by the same ratio's null mean (≈ 1 when well specified).
        chi2_dof: (C,) mean squared whitened residual per channel (≈ 1 if σ is right).
        bands_hz: the bands tested.
        channels: channel names.
        num_draws: simulated null draws.
    """

    p_value: float
    statistic: float
    z_scores: np.ndarray
    band_p: np.ndarray
    band_power_ratio: np.ndarray
    chi2_dof: np.ndarray
    bands_hz: tuple[tuple[float, float], ...]
    channels: tuple[str, ...]
    num_draws: int


def _band_log_ratios(res: np.ndarray, rate: float, bands, ref) -> np.ndarray:
    """res (..., W, L, C) -> (..., C, B) log band-power ratios (periodograms averaged over W)."""
    L = res.shape[-2]
    spec = np.abs(np.fft.rfft(res, axis=-2)) ** 2 / L  # (..., W, F, C)
    spec = spec.mean(axis=-3)  # (..., F, C)
    f = np.fft.rfftfreq(L, 1.0 / rate)
    hi = ref[1] if ref[1] is not None else 0.8 * rate / 2
    ref_m = (f >= ref[0]) & (f <= hi)
    if ref_m.sum() < 4:
        ref_m = f >= 0.5 * f[-1]
    ref_pow = spec[..., ref_m, :].mean(axis=-2)  # (..., C)
    out = []
    for lo, up in bands:
        m = (f >= lo) & (f < up)
        if not m.any():
            m = np.abs(f - 0.5 * (lo + up)) == np.abs(f - 0.5 * (lo + up)).min()
        out.append(np.log(spec[..., m, :].mean(axis=-2) + 1e-300) - np.log(ref_pow + 1e-300))
    return np.stack(out, axis=-1)  # (..., C, B)


def misspecification_test(
    seed: int | np.random.Generator,
    residuals: np.ndarray,
    jacobian: np.ndarray | None,
    *,
    rate: float,
    channels: Sequence[str],
    num_draws: int = 400,
    bands: Sequence[tuple[float, float]] = DEFAULT_BANDS,
    reference_band: tuple[float, float | None] = REFERENCE_BAND,
) -> MisspecificationTest:
    """Calibrated test of "the residuals are fitted white noise" (see module docstring).

    Args:
        seed: random seed or generator for the simulated null (first, like a PRNG key).
        residuals: (W, L, C) whitened residuals on W contiguous stretches of L samples.
        jacobian: (W·L·C, K) Jacobian of the flattened residuals w.r.t. the K fitted
            parameters, rows in `residuals.reshape(-1)` order; None if nothing was fitted.
        rate: sample rate, Hz.
        channels: C channel names.
        num_draws: simulated null draws.
        bands: low bands to test, Hz.
        reference_band: (low, high) Hz of the noise reference; high None = 0.8·Nyquist.

    Returns:
        `MisspecificationTest`.
    """
    rng = np.random.default_rng(seed)
    res = np.asarray(residuals, dtype=float)
    if res.ndim != 3:
        raise ValueError(f"residuals: expected (W, L, C), got shape {res.shape}")
    bands = tuple(tuple(b) for b in bands)
    obs = _band_log_ratios(res, rate, bands, reference_band)  # (C, B)
    q = _fitted_directions(jacobian, res.size)
    null = _null_log_ratios(rng, q, res.shape, num_draws, rate, bands, reference_band)  # (D, C, B)
    mu, sd = null.mean(0), null.std(0) + 1e-12
    z_obs = (obs - mu) / sd
    z_null = (null - mu) / sd
    t_obs = float(z_obs.max())
    t_null = z_null.reshape(num_draws, -1).max(-1)
    p = float((1 + np.sum(t_null >= t_obs)) / (1 + num_draws))
    band_p = (1 + (z_null >= z_obs[None]).sum(0)) / (1 + num_draws)
    return MisspecificationTest(
        p_value=p,
        statistic=t_obs,
        z_scores=z_obs,
        band_p=band_p,
        band_power_ratio=np.exp(obs - mu),
        chi2_dof=np.mean(res**2, axis=(0, 1)),
        bands_hz=bands,
        channels=tuple(channels),
        num_draws=num_draws,
    )


def _fitted_directions(jacobian: np.ndarray | None, n: int) -> np.ndarray:
    """(n, K') orthonormal basis of the Jacobian's column space: the residual directions the
    fit absorbed, which the simulated null must lose too."""
    if jacobian is None or not jacobian.size:
        return np.zeros((n, 0))
    jac = np.asarray(jacobian, dtype=float)
    if jac.shape[0] != n:
        raise ValueError(f"jacobian: expected {n} rows, got {jac.shape[0]}")
    u, s, _ = np.linalg.svd(jac, full_matrices=False)
    return u[:, s > 1e-10 * max(s.max(), 1e-300)]


def _null_log_ratios(rng, q: np.ndarray, shape, num_draws: int, rate: float, bands, ref) -> np.ndarray:
    """(D, C, B) band log-ratios of `num_draws` white-noise residuals of `shape` with the
    fitted directions `q` projected out, drawn in chunks to bound memory."""
    n = int(np.prod(shape))
    null = []
    chunk = 50
    for start in range(0, num_draws, chunk):
        m = min(chunk, num_draws - start)
        eps = rng.standard_normal((m, n))
        eps = eps - (eps @ q) @ q.T
        null.append(_band_log_ratios(eps.reshape((m,) + shape), rate, bands, ref))
    return np.concatenate(null)


@dataclasses.dataclass
class Localisation:
    """Where a recording departs from the fitted model beyond noise.

    Attributes:
        channels: channels with a significant departure (any band or window).
        windows: [[t0, t1], ...] s, merged time windows with a significant low-frequency
            residual in any channel.
        bands_hz: [[f0, f1], ...] bands with a significant excess in any channel.
        channel_scores: {channel: max band z-score}.
        window_excess: {channel: [(t0, t1, excess)] per window}: mean square of the
            low-passed whitened residual divided by its white-noise expectation.
        whiteness: {channel: Ljung–Box p-value on the residual (lags up to 0.25 s)}.
        xcorr: {channel: {input: {"peak": normalised cross-correlation, "lag_s": lag of the
            peak (> 0: the residual follows the input), "significant": bool}}}.
    """

    channels: list[str]
    windows: list[list[float]]
    bands_hz: list[list[float]]
    channel_scores: dict
    window_excess: dict
    whiteness: dict
    xcorr: dict


def _merge(intervals, gap):
    out = []
    for a, b in sorted(intervals):
        if out and a <= out[-1][1] + gap:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return out


@dataclasses.dataclass(frozen=True)
class LocaliseSettings:
    """How `locate_mismatch` cuts and tests the residuals.

    Attributes:
        window: time-window length, s.
        smooth: moving-average length, s, applied before the window statistic (low-pass:
            the window excess then measures slow structure, not noise).
        max_lag: largest cross-correlation lag, s.
        alpha: per-cell significance level (Bonferroni-corrected over cells).
    """

    window: float = 2.0
    smooth: float = 0.25
    max_lag: float = 1.0
    alpha: float = 0.01

    def __post_init__(self):
        if not (self.window > 0 and self.smooth >= 0 and self.max_lag >= 0):
            raise ValueError(f"window > 0, smooth >= 0 and max_lag >= 0 wanted, got {self}")
        if not 0 < self.alpha < 1:
            raise ValueError(f"alpha must be in (0, 1), got {self.alpha}")


def locate_mismatch(
    test: MisspecificationTest,
    residuals: np.ndarray,
    times: np.ndarray,
    inputs: np.ndarray,
    *,
    rate: float,
    input_names: Sequence[str] = ("steer", "torque_front", "torque_rear"),
    settings: LocaliseSettings = LocaliseSettings(),
) -> Localisation:
    """Per channel, time window and frequency band: how far the residual departs from noise.

    Args:
        test: the misspecification test on the same residuals.
        residuals: (W, L, C) whitened residuals.
        times: (W, L) time stamps, s.
        inputs: (W, L, I) driver inputs on the same samples.
        rate: Hz.
        input_names: names of the inputs' channels.
        settings: the windows, smoothing, lags and significance level.

    Returns:
        `Localisation`.
    """
    window, smooth, max_lag, alpha = settings.window, settings.smooth, settings.max_lag, settings.alpha
    res = np.asarray(residuals, dtype=float)
    names = test.channels
    chans, bands = _significant_cells(test, alpha)
    win_excess, flagged = _window_excess(res, times, names, rate, window, smooth, alpha)
    chans += [n for n in names if n not in chans and any(e > thr for _, _, e, thr in win_excess[n])]
    return Localisation(
        channels=[n for n in names if n in chans],
        windows=_merge(flagged, gap=1.0 / rate + 1e-9),
        bands_hz=bands,
        channel_scores={n: float(test.z_scores[c].max()) for c, n in enumerate(names)},
        window_excess={n: [row[:3] for row in rows] for n, rows in win_excess.items()},
        whiteness=_whiteness(res, names, rate),
        xcorr=_input_xcorr(res, inputs, names, input_names, rate, max_lag),
    )


def _significant_cells(test: MisspecificationTest, alpha: float) -> tuple[list[str], list[list[float]]]:
    """Channels and frequency bands with a significant (channel, band) cell of ``test``."""
    n_cells = test.z_scores.size
    sig_cells = test.band_p <= max(alpha / n_cells, 1.0 / (1 + test.num_draws))
    # Per-cell significance: the simulated null is too coarse for alpha/n_cells; use the
    # z-score with a Gaussian tail as well.
    z_thr = stats.norm.isf(alpha / n_cells)
    sig_cells = sig_cells & (test.z_scores > z_thr)
    bands = [list(test.bands_hz[b]) for b in range(len(test.bands_hz)) if sig_cells[:, b].any()]
    chans = [test.channels[c] for c in range(sig_cells.shape[0]) if sig_cells[c].any()]
    return chans, bands


def _window_excess(res, times, names, rate, window, smooth, alpha) -> tuple[dict, list]:
    """Per channel, rows ``(t0, t1, excess, threshold)`` of the smoothed residual's mean square
    per time window against its white expectation, and the ``(t0, t1)`` windows above it."""
    W, L, C = res.shape
    m = max(1, int(round(smooth * rate)))
    kern = np.ones(m) / m
    nw = max(1, int(round(window * rate)))
    out: dict = {}
    flagged = []
    for c in range(C):
        rows = []
        for w in range(W):
            ma = np.convolve(res[w, :, c], kern, mode="same")
            for i0 in range(0, L, nw):
                i1 = min(L, i0 + nw)
                if i1 - i0 < nw // 2:
                    continue
                k = (i1 - i0) / m  # ≈ independent averages in the window
                excess = float(np.mean(ma[i0:i1] ** 2) * m)
                # χ²_k/k tail at level alpha / (number of windows × channels).
                thr = stats.chi2.isf(alpha / max(1, C * W * (L // nw)), k) / k
                t0, t1 = float(times[w, i0]), float(times[w, i1 - 1])
                rows.append((t0, t1, excess, thr))
                if excess > thr:
                    flagged.append((t0, t1))
        out[names[c]] = rows
    return out, flagged


def _whiteness(res, names, rate) -> dict[str, float]:
    """Per channel, the Ljung–Box p-value over lags up to 0.25 s, pooled over windows."""
    W, L, C = res.shape
    h = max(2, int(round(0.25 * rate)))
    white = {}
    for c in range(C):
        q, n_tot = 0.0, 0
        for w in range(W):
            x = res[w, :, c] - res[w, :, c].mean()
            den = float(x @ x) + 1e-300
            ac = np.array([float(x[:-k] @ x[k:]) / den for k in range(1, h + 1)])
            q += L * (L + 2) * np.sum(ac**2 / (L - np.arange(1, h + 1)))
            n_tot += h
        white[names[c]] = float(stats.chi2.sf(q, n_tot))
    return white


def _input_xcorr(res, inputs, names, input_names, rate, max_lag) -> dict:
    """Per channel and input, the window-averaged residual–input cross-correlation's peak,
    its lag and whether it exceeds 4/√(W·L)."""
    W, L, C = res.shape
    # a stretch shorter than the longest lag looked at has only its own lags
    lag_n = max(1, min(int(round(max_lag * rate)), L - 1))
    thr_x = 4.0 / np.sqrt(W * L)
    xc: dict = {}
    for c in range(C):
        xc[names[c]] = {}
        for i, iname in enumerate(input_names):
            acc = np.zeros(2 * lag_n + 1)
            for w in range(W):
                r = res[w, :, c] - res[w, :, c].mean()
                u = inputs[w, :, i] - inputs[w, :, i].mean()
                den = np.sqrt(float(r @ r) * float(u @ u)) + 1e-300
                full = np.correlate(r, u, mode="full") / den  # lag k: Σ r[t+k] u[t]
                mid = L - 1
                acc += full[mid - lag_n : mid + lag_n + 1]
            acc /= W
            j = int(np.argmax(np.abs(acc)))
            xc[names[c]][iname] = {
                "peak": float(acc[j]),
                "lag_s": float((j - lag_n) / rate),
                "significant": bool(abs(acc[j]) > thr_x),
            }
    return xc
