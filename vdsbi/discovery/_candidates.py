"""Candidate explanations: "none" and each registered effect alone (sets of several are built
by the forward search); and where the candidates' parameters sit in the fit. Everything is
read from the effect registry (`vdsbi.simulator.effects.EFFECTS`) at call time, so effects registered
after import count."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ..simulator.effects import EFFECTS


def effect_names() -> tuple[str, ...]:
    """The registered effects discovery searches (`searched`), in registry order."""
    return tuple(n for n, cls in EFFECTS.items() if cls.searched)


@dataclasses.dataclass(frozen=True)
class EffectSpace:
    """The effects of a super-model and where their parameters sit in one flat vector.

    Built from the registry by `effect_space()` (at call time), so it includes effects
    registered after import.

    Attributes:
        names: effect names, in registry order.
        slices: each effect's slice of the flat effect-parameter vector.
        lo, hi: (E,) fit bounds of every effect parameter.
        null: (E,) values at which each effect vanishes.
        start: (E,) starting values when an effect is switched on.
        classes: the effect classes by name (registered ones, or e.g. a discovered-term effect).
    """

    names: tuple[str, ...]
    slices: dict[str, slice]
    lo: np.ndarray
    hi: np.ndarray
    null: np.ndarray
    start: np.ndarray
    classes: dict = dataclasses.field(default_factory=dict)

    @property
    def num_params(self) -> int:
        return int(self.lo.size)

    @property
    def max_pair_params(self) -> int:
        """Most effect parameters a candidate may free at once (a triple of the largest three:
        the forward search selects up to three effects)."""
        sizes = sorted((s.stop - s.start for s in self.slices.values()), reverse=True)
        return int(sum(sizes[:3]))


def effect_space(names: Sequence[str] | None = None, extra: Sequence[type] = ()) -> EffectSpace:
    """`EffectSpace` of `names` (default: every registered effect), read from the registry,
    followed by the unregistered effect classes `extra` (e.g. `simulator.effects.term_effect`)."""
    names = effect_names() if names is None else tuple(names)
    classes = [EFFECTS[n] for n in names] + list(extra)
    names = names + tuple(c.name for c in extra)
    stops = np.cumsum([len(c.param_names) for c in classes]).astype(int)
    slices = {n: slice(int(b - len(c.param_names)), int(b)) for n, c, b in zip(names, classes, stops)}
    flat = lambda attr: np.array([x for c in classes for x in attr(c)], dtype=float)
    return EffectSpace(
        names=names,
        slices=slices,
        lo=flat(lambda c: [b[0] for b in c.bounds]),
        hi=flat(lambda c: [b[1] for b in c.bounds]),
        null=flat(lambda c: c.null),
        start=flat(lambda c: c.start),
        classes=dict(zip(names, classes)),
    )


#: Effects whose signatures can look alike on a recording; each group is checked for
#: separability. "cornering_stiffness" stands for a change of θ's C_alpha_f, C_alpha_r.
LOOKALIKE_GROUPS: tuple[tuple[str, ...], ...] = (
    ("road_grade", "rolling_resistance", "sensor_bias"),
    ("road_bank", "imu_misalignment"),
    ("steering_lag", "cornering_stiffness"),
    # a delay of every input acts like a lag of each at low frequency
    ("signal_delay", "steering_lag", "torque_lag"),
    # each scales what the accelerometer reads or what drives it
    ("sensor_scale", "torque_gain", "imu_misalignment"),
    # each raises the tyres' limit μ·F_z; only downforce's grows with speed²
    ("tyre_friction", "downforce"),
)


def single_candidates(names: Sequence[str] | None = None) -> list[tuple[str, ...]]:
    """The effects `names` (default: every registered effect), one at a time."""
    return [(e,) for e in (effect_names() if names is None else names)]


def label(effects: Sequence[str]) -> str:
    return "+".join(effects) if effects else "none"
