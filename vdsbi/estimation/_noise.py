"""The noise model of a fit's compared samples, and the typed choice of how a fit measures it.

On a real drive the residual after the best fit is model error: larger than the sensor noise and
coloured. `ModelError` gives each channel c a scale s_c (its RMS residual at the fit: the Gaussian
likelihood with an unknown variance per channel, profiled) and an integrated autocorrelation time
τ_c, so that its N_c samples count as N_c/τ_c independent ones. `SensorNoise` holds the sensor's
σ_c, white: the hypothesis that the model is right, which a misspecification test rejects.
"""

from __future__ import annotations

import equinox as eqx
import numpy as np

from ..problem import integrated_autocorrelation_time

#: The residual's scale may fall below the recording's sensor-noise estimate down to this share of
#: it: that estimate takes the noise as white, and a real IMU's vibration lies mostly above the
#: problem's filter band, so the filter removes more of it than the estimate assumes; the floor
#: keeps a fit of few effective samples from claiming less noise than it could have fitted away.
SENSOR_SHARE = 0.25


class NoiseModel(eqx.Module):
    """Per-channel noise of the compared samples, as the fit found it.

    Attributes:
        channels: channel names.
        scale: (C,) RMS residual at the fit (≥ `SENSOR_SHARE` of the sensor noise), channel units.
        tau: (C,) integrated autocorrelation time of the residual, in compared samples.
        sensor: (C,) sensor noise std after the problem's filter, channel units.
        samples: (C,) compared samples fitted per channel.
    """

    channels: tuple[str, ...] = eqx.field(static=True)
    scale: np.ndarray
    tau: np.ndarray
    sensor: np.ndarray
    samples: np.ndarray

    @property
    def std(self) -> np.ndarray:
        """Per-sample std of the equivalent independent-sample likelihood: s·√τ."""
        return self.scale * np.sqrt(self.tau)

    @property
    def model_error_ratio(self) -> np.ndarray:
        """Residual scale over sensor noise: ≈ 1 when the model explains the drive."""
        return self.scale / self.sensor

    def to_dict(self) -> dict:
        return {
            c: {
                "residual_rms": float(s),
                "sensor_std": float(n),
                "model_error_ratio": float(s / n),
                "autocorrelation_time": float(t),
                "effective_samples": float(k / t),
            }
            for c, s, t, n, k in zip(self.channels, self.scale, self.tau, self.sensor, self.samples)
        }


class SensorNoise(eqx.Module):
    """Sensor noise only: white, each channel's σ after the problem's filter; the fit's weights are
    never re-estimated."""


class ModelError(eqx.Module):
    """Sensor noise and the model's own error: after each fit, each channel's scale and
    autocorrelation time are re-measured from its residual (`measure_noise`) and the fit repeated.

    Attributes:
        passes: re-measurements after the first fit (0: fit once with `start`'s weights, then
            measure).
        start: the first fit's noise model (a previous fit's of the same channels, so that a refit
            does not weigh the channels by their spread and leave the basin that fit found);
            default: each channel's spread.
    """

    passes: int = 2
    start: NoiseModel | None = None


def measure_noise(residual: np.ndarray, mask: np.ndarray, sensor: np.ndarray, channels) -> NoiseModel:
    """The `NoiseModel` of a (W, K, C) residual in channel units on its `mask`ed samples."""
    n = mask.sum()
    scale = np.maximum(np.sqrt(np.sum(residual**2, axis=(0, 1)) / max(n, 1)), SENSOR_SHARE * sensor)
    tau = integrated_autocorrelation_time(residual, mask)
    return NoiseModel(tuple(channels), scale, tau, sensor, n * np.ones_like(scale))
