"""`IdentifyResult`: what `identify` returns — the neural posterior, the reported posterior's
draws, posterior.json's content, the problems it was fitted and validated on, the predictive band
and the draws for predicting other driving — with `table` (the printed summary) and `to_json`."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..diagnostics import ridge_sentence

if TYPE_CHECKING:  # annotations only
    from ..inference import Posterior
    from ..problem import Problem


@dataclasses.dataclass
class IdentifyResult:
    """What `identify` found.

    Attributes:
        neural_posterior: the trained neural posterior (`vdsbi.inference.Posterior`), for
            `vdsbi sample`; it proposes the likelihood fit's starts, the reported posterior is the
            likelihood one (`samples`, `estimate`).
        samples: (num_samples, P) draws of the reported (likelihood) posterior, names order.
        summary: the content of posterior.json (parameters with their estimate, noise model,
            combinations, validation, predictive check, warnings).
        out_dir: where the files were written, or None.
        problem: the whole drive's `vdsbi.problem.Problem` (every usable window).
        ppc: the posterior-predictive 5/50/95 % band on `validation`'s windows.
        validation: the problem whose held-out part the band and the validation scores are on
            (`problem` itself when nothing is held out).
        predictive: (ppc_draws, P) parameter draws for predicting other driving at the estimate
            (the `predictive_draws` of `vdsbi.estimation.fit_likelihood`'s posterior, held against
            the likelihood by `vdsbi.estimation.screened_sample`), what `predict --band` uses.
    """

    neural_posterior: Posterior
    samples: np.ndarray
    summary: dict[str, Any]
    out_dir: Path | None = None
    problem: Problem | None = None
    ppc: dict[str, Any] | None = None
    validation: Problem | None = None
    predictive: np.ndarray | None = None

    @property
    def names(self) -> tuple[str, ...]:
        """The parameters, `samples`' column order."""
        return tuple(self.summary["parameters"])

    @property
    def estimate(self) -> dict[str, float]:
        """The best fit by parameter name: what `export` writes and `predict` simulates."""
        return {n: float(p["estimate"]) for n, p in self.summary["parameters"].items()}

    @property
    def interval(self) -> dict[str, tuple[float, float]]:
        """The reported posterior's 90 % interval by parameter name."""
        return {n: (float(p["q05"]), float(p["q95"])) for n, p in self.summary["parameters"].items()}

    @property
    def identified(self) -> dict[str, bool]:
        """Whether the drive identifies each parameter alone (see `table` for why not)."""
        return {n: p.get("identified") is not False for n, p in self.summary["parameters"].items()}

    def table(self) -> str:
        """Per parameter: the estimate (the best fit, what `export` writes and `predict` simulates),
        the posterior's std and 5/50/95 % quantiles; a parameter the drive does not identify alone
        is marked so with its prior range and the reason (no information, held by the prior box,
        or trading with another along a ridge), one the model error moves is marked; then the
        combinations the drive determines, the pairs that trade, and the warnings."""
        width = max(10, *(len(n) for n in self.summary["parameters"]))
        rows = [f"{'param':<{width}} {'estimate':>11} {'std':>10} {'q05':>11} {'q50':>11} {'q95':>11}"]
        for name, p in self.summary["parameters"].items():
            note = "  (moved by model error)" if "model_error" in p else ""
            if p.get("identified") is False:
                lo, hi = p["prior"]
                why = p.get("not_identified_because", "")
                note = f"  NOT identified alone (prior {lo:.4g} .. {hi:.4g}){': ' + why if why else ''}"
            rows.append(
                f"{name:<{width}} {p['estimate']:>11.4g} {p['std']:>10.3g} "
                f"{p['q05']:>11.4g} {p['q50']:>11.4g} {p['q95']:>11.4g}{note}"
            )
        combinations = self.summary.get("combinations", {})
        for key, c in combinations.items():
            if key in ("determined_directions", "trading_pairs"):
                continue
            at = f" at {c['at']} m/s" if c.get("at") else ""
            told = "" if c.get("identified", True) else " (not identified: near its prior spread)"
            rows.append(
                f"{key.replace('_', ' ')}{at}: {c['median']:.4g} {c['unit']} "
                f"[95 %: {c['q025']:.4g} .. {c['q975']:.4g}]{told}"
            )
        for pair in combinations.get("trading_pairs", ()):
            rows.append(f"{ridge_sentence(pair)}: the drive determines them together, not each alone")
        rows += [f"WARNING: {w['message']}" for w in self.summary.get("warnings", ())]
        return "\n".join(rows)

    def to_json(self) -> str:
        return json.dumps(self.summary, indent=2)
