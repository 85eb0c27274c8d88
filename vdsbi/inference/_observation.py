"""What the estimator sees of one simulated or recorded drive, and the network that embeds it:
the raw trajectories through a 1D-CNN, or handcrafted statistics through an MLP.

Both are trained with a fixed cosine schedule in round 1 (a fresh flow) and the constant rate
with early stopping in later rounds: with a constant rate round 1's early stop moved with float
rounding and left the amortised posterior overconfident. Their epoch counts are the longest
whose amortised posterior passes SBC (`benchmarks/summaries.py`); longer training is
overconfident.
"""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from ._cnn import CNNEmbedding
from ._config import NPEConfig, SequentialSettings, SplineFlowSettings, TrainingSettings
from ._embeddings import AbstractEmbedding, MLPEmbedding
from ._standardize import TrajectoryStandardization
from ._summaries import summary_statistics


class AbstractObservation(eqx.Module):
    """The estimator's x from ONE trajectory of measured channels, and its embedding network.

    Attributes:
        name: the word the command line and the run's record use.
        default_config: the flow and training this embedding is tuned with.
    """

    name: eqx.AbstractClassVar[str]
    default_config: eqx.AbstractClassVar[NPEConfig]

    def __call__(self, readings: Float[Array, "T C"], inputs: Float[Array, "T 3"]) -> Float[Array, "..."]:
        raise NotImplementedError

    def embedding(self, key: PRNGKeyArray, x_shape: tuple[int, ...], out_dim: int) -> AbstractEmbedding:
        raise NotImplementedError


class TrajectoryCNN(AbstractObservation):
    """The raw trajectories, inputs appended as channels so the net can relate response to
    excitation, through a 1D-CNN (`CNNEmbedding`).

    Its training: `later_max_epochs` caps each later round at 30 passes over its new
    simulations, which bounds the time of a whole sequential run. `tail_bound` 4 (default 3):
    beyond the spline interval the flow is the identity, so base draws past ±3 escape the
    splines' contraction to TSNPE's narrow posterior and land near the box edges; a wider
    interval leaves round 1 overconfident under SBC. The trajectories are standardised as
    deviations from the mean simulated trajectory (`TrajectoryStandardization`): all simulations
    share the recording's inputs, and per-channel scaling alone buries small θ-driven differences
    under the manoeuvre's own variation. A config given explicitly is used as given.
    """

    name: ClassVar[str] = "cnn"
    default_config: ClassVar[NPEConfig] = NPEConfig(
        flow=SplineFlowSettings(tail_bound=4.0, x_standardize=TrajectoryStandardization()),
        training=TrainingSettings(
            batch_size=256, learning_rate=1e-3, max_epochs=20, patience=6, cosine_decay=True
        ),
        sequential=SequentialSettings(later_max_epochs=30),
    )

    def __call__(self, readings, inputs):
        return jnp.concatenate([readings, inputs], axis=-1)

    def embedding(self, key, x_shape, out_dim):
        return CNNEmbedding(key, x_shape[-1], out_dim=out_dim)


class StatisticsMLP(AbstractObservation):
    """Handcrafted statistics of the channels (`summary_statistics`) through an MLP."""

    name: ClassVar[str] = "stats"
    default_config: ClassVar[NPEConfig] = NPEConfig(
        training=TrainingSettings(
            batch_size=256, learning_rate=1e-3, max_epochs=30, patience=6, cosine_decay=True
        )
    )

    def __call__(self, readings, inputs):
        return summary_statistics(readings)

    def embedding(self, key, x_shape, out_dim):
        return MLPEmbedding(key, int(np.prod(x_shape)), out_dim, width=128, depth=2)


#: The observations by their names.
OBSERVATIONS: dict[str, AbstractObservation] = {o.name: o for o in (TrajectoryCNN(), StatisticsMLP())}
