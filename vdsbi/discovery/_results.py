"""What discovery returns: a candidate's fit, its ranking row, the discovered terms, the verdict
and the whole diagnosis. Each is built once, complete, and not changed afterwards."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from ..diagnostics import Localisation, MisspecificationTest
from ..problem import Problem

if TYPE_CHECKING:  # annotations only (the fitter imports this module)
    from ..problem.points import Point
    from ._fit import Fitter


@dataclasses.dataclass(frozen=True, eq=False)
class DiscoveryFit:
    """A converged (or best-found) MAP fit of one candidate explanation.

    Attributes:
        effects: names of the active effects.
        z: the fit's `Point` (θ, start-speed offsets and every effect's parameters, unbounded).
        theta: (6,) θ in PARAM_NAMES order.
        theta_std: (6,) Laplace std of θ.
        v0: (W,) fitted initial speeds of the fitted windows, m/s.
        effect_params: {effect: {param: value}}.
        effect_std: {effect: {param: Laplace std}}.
        chi2: Σ r² over the fitted samples (residual whitened by the sensor noise).
        num_samples: number of fitted residual entries N.
        num_params: number of free parameters K (θ, initial speeds, effect parameters).
        residual: (N,) residual whitened by the sensor noise, (W, K_t, C) flattened; masked entries 0.
        jacobian: (N, K) Jacobian of the residual along the free entries of z.
        free: (K,) indices of the free entries of z, flattened (`vdsbi.problem.points.positions`).
        iterations: LM iterations used.
        converged: whether the relative cost change fell below tolerance.
        cov: (K, K) the estimator's covariance of the free entries of z (model error in its
            noise model; start speeds from their own information).
        rss: (C,) Σ residual² per channel over the fitted samples, channel units.
        noise: the estimator's noise model at the fit (`vdsbi.estimation.NoiseModel`).
        theta_interval: (6, 2) the estimator's 90 % interval of θ.
    """

    effects: tuple[str, ...]
    z: Point
    theta: np.ndarray
    theta_std: np.ndarray
    v0: np.ndarray
    effect_params: dict
    effect_std: dict
    chi2: float
    num_samples: int
    num_params: int
    residual: np.ndarray
    jacobian: np.ndarray
    free: np.ndarray
    iterations: int
    converged: bool
    cov: np.ndarray
    rss: np.ndarray | None = None
    noise: Any = None
    theta_interval: np.ndarray | None = None

    @property
    def chi2_dof(self) -> float:
        return self.chi2 / max(1, self.num_samples - self.num_params)


@dataclasses.dataclass(frozen=True, eq=False)
class Ranked:
    """One candidate in the evidence ranking (`rank`)."""

    name: str
    effects: tuple[str, ...]
    score: float
    log_bayes_factor: float
    probability: float
    chi2: float
    num_effect_params: int
    fit: DiscoveryFit


@dataclasses.dataclass(frozen=True, eq=False)
class TermDiscovery:
    """The discovered terms (possibly none), their refit and where the search looked.

    Attributes:
        terms: one dict per kept term: key, formula, coefficient, std, unit, target,
            linear_gain (evidence at selection), rms_change {channel: RMS change of the fit}.
        fit: the refit with the chosen effects and the kept terms (None: no term kept).
        fitter: the `Fitter` of that refit (for predictions).
        effects: the effect names of the refit (the chosen ones and `TERM_EFFECT`).
        screened: linearised evidence gain of every candidate term at the first step.
        gain: log Bayes factor of the refit against the library fit (None: no refit).
        dropped: library effects removed beside the terms (they were standing in for them).
    """

    terms: list[dict]
    fit: DiscoveryFit | None
    fitter: Fitter | None
    effects: tuple[str, ...]
    screened: dict[str, float]
    gain: float | None
    dropped: list[str] = dataclasses.field(default_factory=list)


@dataclasses.dataclass(frozen=True)
class Verdict:
    """The conclusion of a diagnosis.

    Attributes:
        detected: the base model's residual test rejected it.
        chosen: the effects chosen as the explanation, beyond the base set (empty: none).
        explained: whether they account for the whole mismatch (None: nothing detected).
        held_out_improved: whether they also improve the held-out fit (None: none chosen).
        explanation: "library", "discovered term", "unexplained" or "none".
        text: the one-line conclusion.
        dropped: effects of the base set (identify's defaults) the chosen set leaves out.
    """

    detected: bool
    chosen: tuple[str, ...]
    explained: bool | None
    held_out_improved: bool | None
    explanation: Literal["library", "discovered term", "unexplained", "none"]
    text: str
    dropped: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True, eq=False)
class DiagnosisResult:
    """Everything `diagnose_mismatch` found; `report` is what report.json holds.

    Attributes:
        report: report.json's content.
        verdict: the conclusion.
        windows: the problem the diagnosis ran on.
        base, final: the fits of the base model and of the chosen explanation.
        ranked: every candidate fitted, best first.
        test_before, test_after: the residual tests of the base and the final fit.
        localisation: where the base fit's residual departs from noise.
        held_out: per channel held-out scores ("before", "after", and "after_terms" with
            discovered terms), as `held_out_scores`.
        predictions: (W, K, C) whole-window predictions, same keys.
        variances: their variances from the fits' parameter uncertainty, same keys.
        residual_stretches: contiguous training stretches of the whitened residual
            ("before", "after": (W, L, C)) and their times ("t": (W, L)).
        terms: the term search (None: not run).
        test_terms: the residual test with the discovered terms (None: none kept).
    """

    report: dict[str, Any]
    verdict: Verdict
    windows: Problem
    base: DiscoveryFit
    final: DiscoveryFit
    ranked: list[Ranked]
    test_before: MisspecificationTest
    test_after: MisspecificationTest
    localisation: Localisation
    held_out: dict[str, dict]
    predictions: dict[str, np.ndarray]
    variances: dict[str, np.ndarray]
    residual_stretches: dict[str, np.ndarray]
    terms: TermDiscovery | None = None
    test_terms: MisspecificationTest | None = None

    @property
    def chosen(self) -> list[str]:
        return list(self.verdict.chosen)

    @property
    def mismatch_detected(self) -> bool:
        return self.verdict.detected
