"""1D-CNN embedding of raw (time × channels) trajectories, trained jointly with the flow."""

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from ._embeddings import AbstractEmbedding, register_embedding


@register_embedding
class CNNEmbedding(AbstractEmbedding):
    """Strided, dilated 1D convolutions, then adaptive average pooling into `num_pool`
    windows (coarse timing survives, any length ≥ `num_pool`·stride works), concatenated with
    per-channel global mean and log-std, then an MLP.

    Input: one standardised trajectory of shape (T, in_channels), channels last.

    Attributes:
        in_channels: number of channels (measured channels plus, optionally, the inputs).
        out_dim: embedding size.
        width: convolution channels.
        num_pool: adaptive-pooling windows along time.
        downsample: average-pooling factor applied first (200 Hz → 25 Hz for 8): vehicle
            body dynamics live below ~5 Hz and it makes training 8× cheaper.
    """

    convs: tuple[eqx.nn.Conv1d, ...]
    head: eqx.nn.MLP
    in_channels: int = eqx.field(static=True)
    out_dim: int = eqx.field(static=True)
    width: int = eqx.field(static=True)
    num_pool: int = eqx.field(static=True)
    downsample: int = eqx.field(static=True)

    def __init__(
        self,
        key: PRNGKeyArray,
        in_channels: int,
        out_dim: int = 32,
        width: int = 24,
        num_pool: int = 8,
        downsample: int = 8,
    ):
        self.in_channels, self.out_dim, self.width = int(in_channels), int(out_dim), int(width)
        self.num_pool, self.downsample = int(num_pool), int(downsample)
        keys = jax.random.split(key, 5)
        # (kernel, stride, dilation): receptive field ≈ 2.5 s at 25 Hz.
        layout = ((5, 1, 1), (5, 2, 1), (5, 1, 2), (5, 2, 2))
        chans = [self.in_channels] + [self.width] * len(layout)
        self.convs = tuple(
            eqx.nn.Conv1d(
                chans[i],
                chans[i + 1],
                k,
                stride=s,
                dilation=d,
                padding="SAME" if s == 1 else k // 2 * d,
                key=keys[i],
            )
            for i, (k, s, d) in enumerate(layout)
        )
        # Head input: pooled conv features plus each input channel's global mean and log-std
        # (global statistics pooling), so level differences such as ω_f vs ω_r slip need not
        # be learned through the convolutions.
        self.head = eqx.nn.MLP(
            self.width * self.num_pool + 2 * self.in_channels,
            self.out_dim,
            128,
            2,
            activation=jax.nn.gelu,
            key=keys[4],
        )

    def __call__(self, x: Float[Array, "T C"]) -> Float[Array, " out_dim"]:
        if x.ndim != 2 or x.shape[-1] != self.in_channels:
            raise ValueError(f"CNNEmbedding expects (T, {self.in_channels}), got {x.shape}")
        t = (x.shape[0] // self.downsample) * self.downsample
        h = x[:t].reshape(t // self.downsample, self.downsample, -1).mean(1).T  # (C, T')
        glob = jnp.concatenate([h.mean(1), 0.5 * jnp.log(h.var(1) + 1e-6)])
        for conv in self.convs:
            h = jax.nn.gelu(conv(h))
        # Adaptive average pooling into num_pool equal windows.
        n = (h.shape[1] // self.num_pool) * self.num_pool
        h = h[:, :n].reshape(h.shape[0], self.num_pool, -1).mean(-1)
        return self.head(jnp.concatenate([h.reshape(-1), glob]))

    def spec(self) -> dict[str, Any]:
        return {
            "in_channels": self.in_channels,
            "out_dim": self.out_dim,
            "width": self.width,
            "num_pool": self.num_pool,
            "downsample": self.downsample,
        }

    @classmethod
    def from_spec(cls, spec):
        return cls(jax.random.key(0), **spec)
