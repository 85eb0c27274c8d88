"""Embedding networks ``x -> R^out_dim`` for ONE example, with a reconstruction registry.

Every embedding is an :class:`AbstractEmbedding`: ``__call__(x)`` maps one
(standardised) observation of fixed shape to a vector of length ``out_dim``, and
``spec()`` returns JSON-serialisable hyperparameters from which
``from_spec(spec)`` rebuilds a skeleton with the same pytree structure (weights
are then filled in by ``eqx.tree_deserialise_leaves``). New embeddings (e.g. the
1D-CNN in ``_cnn.py``) register themselves with :func:`register_embedding`.
"""

import abc
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

_REGISTRY: dict[str, type["AbstractEmbedding"]] = {}


def register_embedding(cls):
    """Class decorator: make ``cls`` reconstructable from ``(cls.__name__, spec)``."""
    _REGISTRY[cls.__name__] = cls
    return cls


def embedding_from_spec(name: str, spec: dict[str, Any]) -> "AbstractEmbedding":
    """Rebuild a skeleton embedding (weights arbitrary) from its registered name and spec."""
    if name not in _REGISTRY:
        raise KeyError(
            f"Unknown embedding {name!r}; registered: {sorted(_REGISTRY)}. "
            "Import the module that defines it (it must use @register_embedding)."
        )
    return _REGISTRY[name].from_spec(spec)


class AbstractEmbedding(eqx.Module):
    """Maps ONE example to ``Float[Array, "out_dim"]``; vmap outside."""

    out_dim: eqx.AbstractVar[int]

    @abc.abstractmethod
    def __call__(self, x: Float[Array, "..."]) -> Float[Array, " out_dim"]: ...

    @abc.abstractmethod
    def spec(self) -> dict[str, Any]:
        """JSON-serialisable hyperparameters; ``from_spec(spec())`` rebuilds the structure."""

    @classmethod
    @abc.abstractmethod
    def from_spec(cls, spec: dict[str, Any]) -> "AbstractEmbedding": ...

    def calibrate(self, xs: Float[Array, "n ..."]) -> "AbstractEmbedding":
        """Data-dependent initialisation from a batch of standardised examples (default: none)."""
        return self


@register_embedding
class IdentityEmbedding(AbstractEmbedding):
    """Flattens x; ``dim`` must equal ``x.size``."""

    out_dim: int = eqx.field(static=True)

    def __init__(self, dim: int):
        self.out_dim = int(dim)

    def __call__(self, x):
        return jnp.reshape(x, (-1,))

    def spec(self):
        return {"dim": self.out_dim}

    @classmethod
    def from_spec(cls, spec):
        return cls(spec["dim"])


@register_embedding
class MLPEmbedding(AbstractEmbedding):
    """Flatten, then an MLP with ``depth`` hidden layers of ``width`` (ReLU), linear output."""

    mlp: eqx.nn.MLP
    in_dim: int = eqx.field(static=True)
    out_dim: int = eqx.field(static=True)
    width: int = eqx.field(static=True)
    depth: int = eqx.field(static=True)

    def __init__(self, key: PRNGKeyArray, in_dim: int, out_dim: int, width: int = 64, depth: int = 2):
        self.in_dim, self.out_dim, self.width, self.depth = int(in_dim), int(out_dim), int(width), int(depth)
        self.mlp = eqx.nn.MLP(in_dim, out_dim, width, depth, activation=jax.nn.relu, key=key)

    def __call__(self, x):
        x = jnp.reshape(x, (-1,))
        if x.shape[0] != self.in_dim:
            raise ValueError(f"MLPEmbedding expects {self.in_dim} inputs, got x of size {x.shape[0]}")
        return self.mlp(x)

    def spec(self):
        return {"in_dim": self.in_dim, "out_dim": self.out_dim, "width": self.width, "depth": self.depth}

    @classmethod
    def from_spec(cls, spec):
        return cls(jax.random.key(0), **spec)
