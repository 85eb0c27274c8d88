"""1D-CNN embedding of raw (time × channels) trajectories, trained jointly with the flow."""

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from ._embeddings import AbstractEmbedding, register_embedding


def _conv_as_products(conv: eqx.nn.Conv1d, h: Float[Array, "C T"]) -> Float[Array, "O T2"]:
    """``conv(h)`` as one dense product over its k shifted (strided, dilated) copies of ``h``.

    The same result and weights, but XLA's CPU convolution is ~6x slower inside the compiled
    training loop (a ``lax.scan``) than outside it, while a dense product is not.
    """
    (k,), (s,), (d,) = conv.kernel_size, conv.stride, conv.dilation
    pads = conv.padding
    if isinstance(pads, str):
        pads = jax.lax.padtype_to_pads((h.shape[1],), (d * (k - 1) + 1,), (s,), pads)
    ((lo, hi),) = pads
    hp = jnp.pad(h, ((0, 0), (lo, hi)))
    n = (hp.shape[1] - d * (k - 1) - 1) // s + 1
    taps = jnp.stack([hp[:, i * d : i * d + s * (n - 1) + 1 : s] for i in range(k)])  # (k, C, n)
    return jnp.einsum("oik,kin->on", conv.weight, taps) + conv.bias


@eqx.filter_jit
def _batch_features(embedding: "CNNEmbedding", xs: Float[Array, "n T C"]) -> Float[Array, "n f"]:
    # compiled: op by op, the features of a large batch cost several times more
    return jax.vmap(embedding.features)(xs)


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
        front_filters: learned strided filters at the full rate, run beside the averaging,
            plus each channel's full-rate first-difference energy as a global statistic (0:
            neither). The tire's slip stiffness shows largely in the wheel/slip-relaxation
            oscillation after torque steps (≈ 20–30 Hz), which averaging to 25 Hz erases.

    The head's input is normalised by statistics frozen at `calibrate` (data-dependent
    initialisation, called by `build_flow`).
    """

    convs: tuple[eqx.nn.Conv1d, ...]
    front: eqx.nn.Conv1d | None
    feature_mean: Float[Array, " f"]
    feature_std: Float[Array, " f"]
    head: eqx.nn.MLP
    in_channels: int = eqx.field(static=True)
    out_dim: int = eqx.field(static=True)
    width: int = eqx.field(static=True)
    num_pool: int = eqx.field(static=True)
    downsample: int = eqx.field(static=True)
    front_filters: int = eqx.field(static=True)

    def __init__(
        self,
        key: PRNGKeyArray,
        in_channels: int,
        out_dim: int = 32,
        width: int = 24,
        num_pool: int = 8,
        downsample: int = 8,
        front_filters: int = 16,
    ):
        self.in_channels, self.out_dim, self.width = int(in_channels), int(out_dim), int(width)
        self.num_pool, self.downsample = int(num_pool), int(downsample)
        self.front_filters = int(front_filters)
        keys = jax.random.split(key, 6)
        ds = self.downsample
        self.front = (
            eqx.nn.Conv1d(self.in_channels, self.front_filters, 2 * ds, stride=ds, key=keys[5])
            if self.front_filters > 0
            else None
        )
        # (kernel, stride, dilation): receptive field ≈ 2.5 s at 25 Hz.
        layout = ((5, 1, 1), (5, 2, 1), (5, 1, 2), (5, 2, 2))
        chans = [self.in_channels + self.front_filters] + [self.width] * len(layout)
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
        num_features = self.width * self.num_pool + (3 if self.front_filters else 2) * self.in_channels
        # Frozen normalisation of the head's input, set by `calibrate` from training data.
        self.feature_mean, self.feature_std = jnp.zeros(num_features), jnp.ones(num_features)
        self.head = eqx.nn.MLP(
            num_features,
            self.out_dim,
            128,
            2,
            activation=jax.nn.gelu,
            key=keys[4],
        )

    def __call__(self, x: Float[Array, "T C"]) -> Float[Array, " out_dim"]:
        mean, std = jax.lax.stop_gradient((self.feature_mean, self.feature_std))
        return self.head((self.features(x) - mean) / std)

    def calibrate(self, xs: Float[Array, "n T C"]) -> "CNNEmbedding":
        """Set the head-input normalisation to the features' mean and std over ``xs``.

        The global statistics vary little across simulations (ω_f's log-std, which carries
        C_kappa, moves by a few hundredths) beside O(1) convolution features; un-normalised,
        the head would need weights hundreds of times its initial scale to use them, which
        Adam's bounded steps do not reach in a training run, and the posterior's C_kappa stayed
        at the prior.
        """
        f = _batch_features(self, xs)
        std = jnp.std(f, axis=0)
        return eqx.tree_at(
            lambda e: (e.feature_mean, e.feature_std),
            self,
            (jnp.mean(f, axis=0), jnp.where(std > 1e-6, std, 1.0)),
        )

    def features(self, x: Float[Array, "T C"]) -> Float[Array, " f"]:
        """The head's input: pooled convolution features and global statistics per channel."""
        if x.ndim != 2 or x.shape[-1] != self.in_channels:
            raise ValueError(f"CNNEmbedding expects (T, {self.in_channels}), got {x.shape}")
        t = (x.shape[0] // self.downsample) * self.downsample
        h = x[:t].reshape(t // self.downsample, self.downsample, -1).mean(1).T  # (C, T')
        glob = jnp.concatenate([h.mean(1), 0.5 * jnp.log(h.var(1) + 1e-6)])
        if self.front is not None:
            d = jnp.diff(x[:t], axis=0)  # full-rate first differences: high-frequency energy
            glob = jnp.concatenate([glob, 0.5 * jnp.log(d.var(0) + 1e-6)])
            # zero past the end, so the strided full-rate filter yields one value per block
            xf = jnp.pad(x[:t].T, ((0, 0), (0, self.downsample)))
            f = _conv_as_products(self.front, xf)[:, : h.shape[1]]
            h = jnp.concatenate([h, jax.nn.gelu(f)], axis=0)
        for conv in self.convs:
            h = jax.nn.gelu(_conv_as_products(conv, h))
        # Adaptive average pooling into num_pool equal windows.
        n = (h.shape[1] // self.num_pool) * self.num_pool
        h = h[:, :n].reshape(h.shape[0], self.num_pool, -1).mean(-1)
        return jnp.concatenate([h.reshape(-1), glob])

    def spec(self) -> dict[str, Any]:
        return {
            "in_channels": self.in_channels,
            "out_dim": self.out_dim,
            "width": self.width,
            "num_pool": self.num_pool,
            "downsample": self.downsample,
            "front_filters": self.front_filters,
        }

    @classmethod
    def from_spec(cls, spec):
        return cls(jax.random.key(0), **spec)
