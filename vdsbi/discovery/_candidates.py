"""Candidate explanations: "none", the ten effects alone, and pairs among the strongest singles."""

from __future__ import annotations

import itertools
from collections.abc import Sequence

from ._fit import EFFECT_NAMES

#: Effects whose signatures can look alike on a recording; each group is checked for
#: separability. "cornering_stiffness" stands for a change of θ's C_alpha_f, C_alpha_r.
LOOKALIKE_GROUPS: tuple[tuple[str, ...], ...] = (
    ("road_grade", "rolling_resistance", "sensor_bias"),
    ("road_bank", "imu_misalignment"),
    ("steering_lag", "cornering_stiffness"),
)


def single_candidates() -> list[tuple[str, ...]]:
    """The ten effects, one at a time."""
    return [(e,) for e in EFFECT_NAMES]


def pair_candidates(ranked_singles: Sequence[str], top: int = 3) -> list[tuple[str, ...]]:
    """Pairs among the `top` best-ranked singles (all 45 pairs cost too much to fit; a pair
    whose members both add nothing alone is rarely the answer, and the pairs that are
    skipped are listed in the report)."""
    best = list(ranked_singles)[:top]
    return [tuple(sorted(p, key=EFFECT_NAMES.index)) for p in itertools.combinations(best, 2)]


def all_pairs() -> list[tuple[str, ...]]:
    return list(itertools.combinations(EFFECT_NAMES, 2))


def label(effects: Sequence[str]) -> str:
    return "+".join(effects) if effects else "none"
