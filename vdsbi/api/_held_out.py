"""Whether a run's estimate predicts the driving it never saw: the verdict `export` reads from
posterior.json's `validation` before it writes a controller file.

The rule, on the lateral channels the exported cornering stiffnesses and l_f govern (ay and
yaw_rate, where scored; every scored channel otherwise): the estimate fitted on the training
part passes when it simulates the held-out part and, on each of those channels, predicts it
better than the channel's own held-out mean (NRMSE below `NRMSE_CEILING`) and not more than
`NPE_MARGIN` times worse than the neural posterior's mean. A fit that loses to the neural
posterior's rough guess on driving neither saw has stopped in a wrong basin, or fits what the
model lacks.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

#: The channels a single-track controller's parameters govern.
LATERAL = ("ay", "yaw_rate")
#: NRMSE at which a prediction is no better than the held-out measurement's mean.
NRMSE_CEILING = 1.0
#: How much worse than the neural posterior mean's held-out NRMSE the estimate's may be: a
#: quarter, so that two fits that predict alike never fail on their noise.
NPE_MARGIN = 1.25


@dataclasses.dataclass(frozen=True)
class HeldOutVerdict:
    """What a run's held-out part says about its estimate.

    Attributes:
        scored: a held-out part was scored (identify ran with `--holdout` > 0).
        passed: the estimate predicts it, by the module's rule (False when not scored).
        channels: {channel: (estimate's held-out NRMSE, the neural posterior mean's or None)}
            over the channels judged.
        held_out_seconds: length of the held-out part, s.
        failures: one line per channel that fails, saying by how much.
    """

    scored: bool
    passed: bool
    channels: dict[str, tuple[float, float | None]]
    held_out_seconds: float = 0.0
    failures: tuple[str, ...] = ()

    def describe(self) -> str:
        """One line: the held-out NRMSE per channel judged, against the neural mean's."""
        if not self.scored:
            return "no held-out part was scored"
        npe = [v for _, v in self.channels.values()]
        scores = ", ".join(f"{c} {e:.3f}" for c, (e, _) in self.channels.items())
        against = (
            ""
            if None in npe
            else " (the neural posterior's mean: " + ", ".join(f"{v:.3f}" for v in npe) + ")"
        )
        return f"held-out {self.held_out_seconds:g} s at NRMSE {scores}{against}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "scored": self.scored,
            "passed": self.passed,
            "nrmse": {c: {"estimate": e, "npe_mean": n} for c, (e, n) in self.channels.items()},
            "held_out_seconds": self.held_out_seconds,
            "failures": list(self.failures),
            "rule": f"on {', '.join(LATERAL)} (where scored): held-out NRMSE < {NRMSE_CEILING:g} and at most "
            f"{NPE_MARGIN:g} x the neural posterior mean's",
        }


def held_out_verdict(post: Mapping[str, Any]) -> HeldOutVerdict:
    """The verdict on posterior.json `post`'s estimate from its `validation` section."""
    val = post.get("validation") or {}
    est = val.get("estimate")
    if not est:
        return HeldOutVerdict(scored=False, passed=False, channels={})
    seconds = float(est.get("held_out_seconds", 0.0))
    scored = est.get("channels") or {}
    if not est.get("ok", True) or not scored:
        why = ("the estimate does not simulate the held-out part (the model leaves its domain there)",)
        return HeldOutVerdict(True, False, {}, seconds, why)
    npe = (val.get("npe_mean") or {}).get("channels") or {}
    judged = [c for c in LATERAL if c in scored] or list(scored)
    channels = {c: (float(scored[c]["nrmse"]), _nrmse(npe.get(c))) for c in judged}
    failures = []
    for c, (e, n) in channels.items():
        if not e < NRMSE_CEILING:
            failures.append(f"{c} NRMSE {e:.3f}: no better than the held-out {c}'s own mean")
        elif n is not None and e > NPE_MARGIN * n:
            failures.append(f"{c} NRMSE {e:.3f} against the neural posterior mean's {n:.3f}")
    return HeldOutVerdict(True, not failures, channels, seconds, tuple(failures))


def _nrmse(scores: Mapping[str, Any] | None) -> float | None:
    return None if not scores else float(scores["nrmse"])
