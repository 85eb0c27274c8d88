"""How `diagnose_mismatch` searches (`DiagnoseSettings`), its default fit, and its progress lines."""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable, Sequence

from ..simulator.models import LongitudinalChoice
from ._candidates import effect_names


@dataclasses.dataclass(frozen=True)
class DiagnoseSettings:
    """How `diagnose_mismatch` searches; every field is also a keyword argument of `diagnose_mismatch`.

    Attributes:
        seed: seed of the simulated null of the misspecification test.
        alpha: level of the misspecification test.
        max_effects: most effects the forward search selects (1: singles only).
        candidates: effects to consider (default: every registered effect).
        base_effects: the effects the search starts from (default: those identify adds by
            default on the drive, `vdsbi.problem.default_effects`, so that what diagnose names is
            what identify lacks); () for θ alone.
        longitudinal: "torque", "speed" or "auto" (see `vdsbi.problem.ProblemSettings`).
        max_window, max_windows: windows cut from the usable stretches (s, count; None: 20 s
            with torques, 10 s following the speed, and all of them).
        train_fraction: share of the usable driving fitted; the rest is held out (whole windows
            at the end of a drive of 3 or more windows, else the end of each window).
        num_draws: simulated null draws of the test.
        single_iters, final_iters: LM iteration caps for the search and the final fit.
        search_dt, final_dt: RK4 steps, s, of the candidate search and of the base/final fits
            (the test and the held-out comparison use the final step).
        workers: threads fitting a search step's candidates side by side (each fit keeps about
            one core busy).
        max_terms: most candidate terms (`simulator.effects.TERMS`) used to describe a mismatch the
            chosen effects leave (p after the fix < alpha); 0: no term search.
        quiet: no progress lines.
        plots: write the figures (with `out_dir`).
    """

    seed: int = 0
    alpha: float = 0.05
    max_effects: int = 3
    candidates: Sequence[str] | None = None
    base_effects: Sequence[str] | None = None
    longitudinal: LongitudinalChoice = "auto"
    max_window: float | None = None
    max_windows: int | None = None
    train_fraction: float = 0.7
    num_draws: int = 400
    single_iters: int = 8
    final_iters: int = 20
    search_dt: float = 0.005
    final_dt: float = 0.0025
    workers: int = 2
    max_terms: int = 3
    quiet: bool = True
    plots: bool = True

    def candidate_names(self) -> tuple[str, ...]:
        """The effects searched, in registry order (read now); ValueError on a name that is not
        one of discovery's candidates (unknown, or registered with `searched = False`)."""
        known = effect_names()
        if self.candidates is None:
            return known
        unknown = set(self.candidates) - set(known)
        if unknown:
            raise ValueError(f"candidates: {sorted(unknown)} not among discovery's candidates {known}")
        return tuple(n for n in known if n in set(self.candidates))


class Progress:
    """Progress lines to `log` (default: printed; none when quiet); `seconds` since the start."""

    def __init__(self, quiet: bool, log: Callable[[str], None] | None = None):
        self.quiet, self.t_start = quiet, time.perf_counter()
        self.log = log or functools.partial(print, flush=True)

    @property
    def seconds(self) -> float:
        return time.perf_counter() - self.t_start

    def __call__(self, msg: str) -> None:
        if not self.quiet:
            self.log(msg)
