"""Forward selection of several effects: add one effect at a time on the refitted model while
the evidence supports it.

Step 1 fits every effect alone on the base fit. If the best has strong evidence (log Bayes
factor ≥ `STRONG`), each later step fits every remaining effect added to the current set
(warm-started from the current set's fit, so θ and the effects already in re-fit jointly) and
keeps the one with the largest evidence gain over the current set, if that gain is strong too;
up to `max_effects` effects. The gain is the log Bayes factor of the larger set against the
current one (`bic_score`), so a strong effect does not hide a weak one (alone, the weak effect
may rank low while the strong one's misfit dominates).

After each addition, each earlier member is tried out again (a backward step): one that no
longer adds strong evidence beside the others is removed — an effect that entered first as a
look-alike of two true ones (e.g. a torque gain standing in for a wheel-radius error) leaves
once they are in.

Ambiguity is reported, not hidden: at each step the other effects whose gain is strong and
within `STRONG` of the best one's are listed as look-alikes the data cannot separate there.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import NamedTuple

from ..runtime import thread_map
from ..simulator.effects import EFFECTS
from ._candidates import label
from ._rank import STRONG, bic_score
from ._results import DiscoveryFit


class Step(NamedTuple):
    """One forward step: the set it started from, the effect it added (None: stopped), the
    evidence gain of every effect tried, the strong rivals of the added one, and an earlier
    member removed by the backward step (None: none)."""

    current: tuple[str, ...]
    added: str | None
    gains: dict[str, float]
    ambiguous_with: list[str]
    removed: str | None = None


class ForwardSearch(NamedTuple):
    fits: dict[tuple[str, ...], DiscoveryFit]  # every candidate fitted, () -> the base fit
    steps: list[Step]
    selected: tuple[str, ...]


def _ordered(effects, names: Sequence[str]) -> tuple[str, ...]:
    """In the registry's order (then `names`'), so a set has one key whatever the path to it."""
    order = [*EFFECTS, *(n for n in names if n not in EFFECTS)]
    return tuple(sorted(effects, key=lambda e: (order.index(e) if e in order else len(order), e)))


def _step(current, names, fits, fit_fn, workers: int) -> Step:
    tried = {e: _ordered(current + (e,), names) for e in names if e not in current}
    todo = [c for c in tried.values() if c not in fits]
    z0 = fits[current].z
    fits.update(zip(todo, thread_map(lambda cand: fit_fn(cand, z0), todo, workers)))
    gains = {e: float(bic_score(fits[cand], fits[current])) for e, cand in tried.items()}
    if not gains:
        return Step(current, None, gains, [])
    best = max(gains, key=gains.get)
    if gains[best] < STRONG:
        return Step(current, None, gains, [])
    rivals = [e for e, g in gains.items() if e != best and g >= STRONG and gains[best] - g < STRONG]
    return Step(current, best, gains, sorted(rivals, key=lambda e: -gains[e]))


def forward_search(
    fit_fn: Callable[[tuple[str, ...], object], DiscoveryFit],
    base: DiscoveryFit,
    names: Sequence[str],
    max_effects: int = 3,
    workers: int = 1,
) -> ForwardSearch:
    """Forward selection over `names` from the effects of `base` (see the module docstring).

    Args:
        fit_fn: `(effects, z0) -> DiscoveryFit`, the fit of a candidate warm-started at z0.
        base: the base model's fit ("none"), with the effects the search starts from (the
            backward step may remove them too).
        names: the candidate effects.
        max_effects: most effects added (1: singles only).
        workers: threads fitting a step's candidates side by side (`thread_map`; fit_fn must
            then be safe to call from several threads at once).

    Returns:
        `ForwardSearch`: all fits, the steps taken, and the selected effects (possibly none).
    """
    fits: dict[tuple[str, ...], DiscoveryFit] = {tuple(base.effects): base}
    steps: list[Step] = []
    current: tuple[str, ...] = tuple(base.effects)
    names = tuple(n for n in names if n not in current)
    # bounded: each step adds one effect and removes at most one
    for _ in range(2 * max(1, max_effects) + 2):
        if len(set(current) - set(base.effects)) >= max(1, max_effects):
            break
        step = _step(current, tuple(names), fits, fit_fn, workers)
        if step.added is None:
            steps.append(step)
            break
        current = _ordered(current + (step.added,), names)
        current, removed = _prune(current, step.added, fits, fit_fn)
        steps.append(step._replace(removed=removed))
    return ForwardSearch(fits, steps, current)


def _prune(current, added, fits, fit_fn):
    """The backward step: drop the first earlier member whose removal costs < `STRONG`."""
    for e in current:
        if e == added:
            continue
        sub = tuple(x for x in current if x != e)
        refit = fit_fn(sub, fits[current].z)  # warm-started from the larger set
        if sub not in fits or refit.chi2 < fits[sub].chi2:
            fits[sub] = refit
        if bic_score(fits[current], fits[sub]) < STRONG:
            return sub, e
    return current, None


def describe(steps: Sequence[Step]) -> list[dict]:
    """report.json's record of the search: one entry per step."""
    out = []
    for s in steps:
        top = sorted(s.gains.items(), key=lambda kv: -kv[1])[:4]
        out.append(
            {
                "from": label(s.current),
                "added": s.added,
                "gain": s.gains.get(s.added) if s.added else None,
                "best_gains": {e: g for e, g in top},
                "ambiguous_with": s.ambiguous_with,
                "removed": s.removed,
            }
        )
    return out
