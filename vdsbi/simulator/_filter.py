"""Anti-alias low-pass and decimation: one kernel for measured and simulated channels.

Measured data and simulated readings must be filtered by the same operator, or the
inference learns the difference between the two filters. `Decimator` is that operator: a
zero-phase FIR applied with jnp, so it runs on numpy arrays (a recording's channels) and
inside jit/vmap on simulated (T, C) readings alike, and gradients flow through it.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float


class Decimator(eqx.Module):
    """Zero-phase windowed-sinc (Hamming) low-pass, then keep every `factor`-th sample.

    The filter is symmetric and odd-length, centred on each kept sample, so it delays
    nothing: output k is the filtered signal at input sample k·factor (`output_times`).
    The length follows from the transition width Δf (default: the cutoff itself): Hamming's
    main lobe needs N ≈ 3.3·rate/Δf taps; its gain is 1 ± 0.2 % below cutoff − Δf/2 and
    below −50 dB above cutoff + Δf/2. The taps sum to 1 exactly (DC passes unchanged).

    Edges are padded by odd reflection through the end value (2·y₀ − y_k, scipy's filtfilt
    default): it keeps value and slope, so a ramp passes unchanged. Within `edge_samples`
    output samples of either end the padding matters: the end sample itself carries much of
    the weight there, so its high-frequency content (noise, vibration) is attenuated less
    than in the interior.

    Attributes:
        rate: input sample rate, Hz.
        cutoff: −6 dB frequency, Hz; at most the output Nyquist rate/(2·factor).
        factor: integer decimation factor (1: filter only).
        transition: transition width Δf, Hz; None for Δf = cutoff.
    """

    rate: float = eqx.field(static=True)
    cutoff: float = eqx.field(static=True)
    factor: int = eqx.field(static=True, default=1)
    transition: float | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        if not (isinstance(self.factor, int) and self.factor >= 1):
            raise ValueError(f"decimator: factor must be an integer >= 1, got {self.factor!r}")
        if not (math.isfinite(self.rate) and self.rate > 0):
            raise ValueError(f"decimator: rate must be a positive number of Hz, got {self.rate!r}")
        nyquist_out = self.rate / (2 * self.factor)
        if not (self.cutoff > 0 and self.cutoff <= nyquist_out and self.cutoff < self.rate / 2):
            raise ValueError(
                f"decimator: cutoff {self.cutoff!r} Hz must lie in (0, {nyquist_out}] "
                f"(the output Nyquist rate of {self.rate} Hz / {self.factor})"
            )
        if self.transition is not None and not self.transition > 0:
            raise ValueError(f"decimator: transition must be > 0 Hz, got {self.transition!r}")

    @property
    def half_length(self) -> int:
        """Taps on each side of the centre tap."""
        width = self.cutoff if self.transition is None else self.transition
        return max(1, math.ceil(1.65 * self.rate / width))

    @property
    def num_taps(self) -> int:
        return 2 * self.half_length + 1

    @property
    def edge_samples(self) -> int:
        """Output samples at each end whose filter window reaches into the padding."""
        return math.ceil(self.half_length / self.factor)

    @property
    def output_rate(self) -> float:
        return self.rate / self.factor

    @property
    def taps(self) -> np.ndarray:
        """(num_taps,) float64 filter coefficients, symmetric, summing to 1."""
        n = np.arange(-self.half_length, self.half_length + 1)
        fc = self.cutoff / self.rate
        h = 2 * fc * np.sinc(2 * fc * n) * np.hamming(self.num_taps)
        return h / h.sum()

    def num_out(self, num_samples: int) -> int:
        """Number of output samples for `num_samples` inputs: ceil(T / factor)."""
        return (num_samples - 1) // self.factor + 1

    def output_times(self, t: Float[Array, " T"]) -> Float[Array, " T_out"]:
        """Times of the output samples: every `factor`-th input time, from the first."""
        return t[:: self.factor]

    def __call__(self, ys: Float[Array, "T ..."]) -> Float[Array, "T_out ..."]:
        """Filter along axis 0 and decimate (one example; vmap outside for batches).

        Args:
            ys: (T,) or (T, C) samples at `rate` (numpy or jax).

        Returns:
            (num_out(T),) or (num_out(T), C), in the input's floating dtype.

        Raises:
            ValueError: if T ≤ half_length (too short to pad by reflection).
        """
        ys = jnp.asarray(ys)
        if not jnp.issubdtype(ys.dtype, jnp.floating):
            ys = ys.astype(float)
        squeeze = ys.ndim == 1
        x = ys[:, None] if squeeze else ys.reshape(ys.shape[0], -1)
        num, half = x.shape[0], self.half_length
        if num <= half:
            raise ValueError(
                f"decimator: {num} samples are too few for a {self.num_taps}-tap filter "
                f"with reflected edges (need > {half}); use a higher cutoff"
            )
        head = 2 * x[:1] - x[half:0:-1]
        tail = 2 * x[-1:] - x[-2 : -half - 2 : -1]
        padded = jnp.concatenate([head, x, tail])  # (T + 2·half, C)
        channels = x.shape[1]
        kernel = jnp.broadcast_to(jnp.asarray(self.taps, dtype=x.dtype), (channels, 1, self.num_taps))
        # One grouped 1-D convolution per channel with the stride doing the decimation, so only
        # the kept samples are computed. HIGHEST precision: GPUs would otherwise use TF32 for
        # a float32 convolution, a 1e-3 relative error on every reading.
        out = jax.lax.conv_general_dilated(
            padded.T[None],  # (1, C, T + 2·half)
            kernel,  # (C, 1, N)
            window_strides=(self.factor,),
            padding="VALID",
            dimension_numbers=("NCH", "OIH", "NCH"),
            feature_group_count=channels,
            precision=jax.lax.Precision.HIGHEST,
        )[0].T  # (T_out, C)
        return out[:, 0] if squeeze else out.reshape((out.shape[0],) + ys.shape[1:])
