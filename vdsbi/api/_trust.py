"""Whether a posterior can be trusted: mass piled at the prior's edges, or a posterior-predictive
band that misses the recording, each a sign of a wrong model (or a too narrow prior box)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

#: Share of the prior box's width counted as "at an edge".
EDGE = 0.02
#: A parameter piles at an edge when more than this share of its samples lies within `EDGE` of
#: it; a posterior as flat as the prior puts `EDGE` (2 %) there, so this is 12x that.
PILE = 0.25
#: A channel misses when less than this share of the recording lies inside the 90 % predictive
#: band (nominal 0.90; a right model with a sound posterior is near 0.9 or above).
MISS = 0.5
#: A channel's model error is worth diagnosing when its residual after the best fit exceeds the
#: sensor noise this many times.
MODEL_ERROR = 3.0


def edge_mass(samples: np.ndarray, box: Sequence[tuple[float, float]]) -> np.ndarray:
    """(P, 2): share of (N, P) `samples` within `EDGE` of the box width from the lower and the
    upper edge."""
    lo, hi = np.asarray(box, dtype=float).T
    margin = EDGE * (hi - lo)
    return np.stack([(samples <= lo + margin).mean(0), (samples >= hi - margin).mean(0)], axis=1)


def trust_warnings(
    samples: np.ndarray,
    names: Sequence[str],
    box: Mapping[str, tuple[float, float]],
    skip: Sequence[str],
    coverage: Mapping[str, Mapping[str, float | None]],
    diagnose_command: str,
) -> list[dict[str, Any]]:
    """Warnings about a posterior (empty when none applies), each with a one-line `message`.

    Args:
        samples: (N, P) posterior draws, `names` order.
        box: the uniform prior's box by name.
        skip: parameters not checked for edges (those the drive cannot inform: their posterior
            is the prior's).
        coverage: {"train": {channel: share inside the 90 % band}, "held_out": {...}} (None
            where no draw simulated).
        diagnose_command: what to run next, named in every message.
    """
    out = []
    mass = edge_mass(samples, [box[n] for n in names])
    piled = {
        n: {"edge": "lower" if m[0] >= m[1] else "upper", "fraction": float(m.max())}
        for n, m in zip(names, mass)
        if n not in skip and m.max() > PILE
    }
    if piled:
        what = ", ".join(
            f"{n} ({v['fraction']:.0%} of samples at the {v['edge']} edge)" for n, v in piled.items()
        )
        out.append(
            {
                "kind": "prior_edge",
                "parameters": piled,
                "message": f"posterior piled at the prior's edge: {what}; the model may be missing "
                f"physics the parameters absorb (or the prior box is too narrow): run `{diagnose_command}`",
            }
        )
    missed = _missed(coverage)
    if missed:
        what = ", ".join(f"{c} ({f:.0%} inside)" for c, f in missed.items())
        out.append(
            {
                "kind": "predictive_miss",
                "channels": missed,
                "message": f"the posterior-predictive 90 % band misses the recording on {what}; "
                "the model does not reproduce these channels, or (where only the held-out part is "
                f"missed) the fitted part does not inform what they depend on: run `{diagnose_command}`",
            }
        )
    return out


def model_error_warning(noise_model: Mapping[str, Mapping[str, float]], diagnose_command: str) -> list[dict]:
    """A warning (empty list when none) naming the channels the best fit misses by more than
    `MODEL_ERROR` times their sensor noise: the intervals hold the model error, but something the
    model lacks may be found and modelled."""
    ratios = {c: float(v["model_error_ratio"]) for c, v in noise_model.items()}
    worse = {c: r for c, r in ratios.items() if r > MODEL_ERROR}
    if not worse:
        return []
    what = ", ".join(f"{c} ({r:.1f}× its sensor noise)" for c, r in worse.items())
    return [
        {
            "kind": "model_error",
            "channels": worse,
            "message": f"the best fit misses {what}; the intervals include that model error, but the "
            f"model may lack physics the recording has: run `{diagnose_command}`",
        }
    ]


def _missed(coverage: Mapping[str, Mapping[str, float | None]]) -> dict[str, float]:
    """{channel: lowest share inside the band over the fitted and held-out parts} below `MISS`."""
    worst: dict[str, float] = {}
    for part in coverage.values():
        for c, f in part.items():
            if f is not None:
                worst[c] = min(worst.get(c, 1.0), f)
    return {c: f for c, f in worst.items() if f < MISS}
