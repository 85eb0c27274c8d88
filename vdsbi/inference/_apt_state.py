"""The state of a sequential run between rounds, and its one-file checkpoint."""

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import PRNGKeyArray

from ._estimator import AbstractEstimator
from ._serialise import FORMAT_VERSION, flow_from_bytes, flow_to_bytes, read_npz, write_npz


@dataclasses.dataclass(frozen=True)
class APTState:
    """Everything needed to resume :func:`apt` exactly after a finished round.

    Attributes:
        round: number of completed rounds.
        key: the PRNG key the next round starts from.
        theta: ``(N, d)`` parameters of all kept (valid, finite) simulations so far.
        x: ``(N, ...)`` their simulations.
        round_ids: ``(N,)`` round in which each simulation was made (0 = prior draws).
        is_val: ``(N,)`` held out for validation (fixed when the simulation is made).
        flow: the current estimator (None before round 1 finishes).
        history: one dict per round: simulation counts (incl. ``num_invalid``,
            ``num_nonfinite``, ``num_used``), proposal, epochs, losses, wall time.
    """

    round: int
    key: PRNGKeyArray
    theta: np.ndarray
    x: np.ndarray
    round_ids: np.ndarray
    is_val: np.ndarray
    flow: AbstractEstimator | None
    history: tuple[dict[str, Any], ...] = ()

    @property
    def num_invalid(self) -> int:
        """Total simulations discarded (``valid=False`` or non-finite) over all rounds."""
        return sum(h["num_invalid"] + h["num_nonfinite"] for h in self.history)


def save_state(path, state: APTState) -> None:
    """Write ``state`` to ONE file atomically (temp file + ``os.replace``)."""
    header = {
        "kind": "APTState",
        "version": FORMAT_VERSION,
        "round": state.round,
        "history": list(state.history),
        "flow": None if state.flow is None else state.flow.spec(),
    }
    arrays = {
        "key": np.asarray(jax.random.key_data(state.key)),
        "theta": state.theta,
        "x": state.x,
        "round_ids": state.round_ids,
        "is_val": state.is_val,
    }
    if state.flow is not None:
        arrays["flow"] = flow_to_bytes(state.flow)
    write_npz(path, header, arrays)


def load_state(path, like: APTState | None = None) -> APTState:
    """Read a state written by :func:`save_state`.

    ``like`` is accepted for API symmetry; the estimator is rebuilt from the stored spec.
    """
    del like
    header, arrays = read_npz(path)
    if header.get("kind") != "APTState":
        raise ValueError(f"{path} does not hold an APTState (kind={header.get('kind')!r})")
    flow = None if header["flow"] is None else flow_from_bytes(header["flow"], arrays["flow"])
    return APTState(
        round=int(header["round"]),
        key=jax.random.wrap_key_data(jnp.asarray(arrays["key"])),
        theta=arrays["theta"],
        x=arrays["x"],
        round_ids=arrays["round_ids"],
        is_val=arrays["is_val"],
        flow=flow,
        history=tuple(header["history"]),
    )
