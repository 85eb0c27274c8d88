"""The sbibm benchmark tasks in JAX, with reference posterior samples we generate ourselves."""

from ._base import AbstractTask as AbstractTask, rejection as rejection
from ._gaussian_linear_uniform import GaussianLinearUniform as GaussianLinearUniform
from ._gaussian_mixture import GaussianMixture as GaussianMixture
from ._slcp import SLCP as SLCP, slcp_log_likelihood as slcp_log_likelihood
from ._two_moons import TwoMoons as TwoMoons

TASKS = {
    "two_moons": TwoMoons,
    "slcp": SLCP,
    "gaussian_linear_uniform": GaussianLinearUniform,
    "gaussian_mixture": GaussianMixture,
}


def get_task(name: str) -> AbstractTask:
    """Instantiate a task by its sbibm name."""
    if name not in TASKS:
        raise KeyError(f"unknown task {name!r}; available: {sorted(TASKS)}")
    return TASKS[name]()
