"""One drive answered on a worker: the platform's amortized posterior, checked against the
likelihood; else a likelihood fit started from it, checked again; else the full `identify`.

Levels (the `method` of estimates.csv):

* ``amortized``: the amortized posterior passed the importance check; the answer is its
  importance-weighted draws.
* ``amortized+fit``: the likelihood fit (`vdsbi.estimation.fit_likelihood`) started from the
  best of the amortized check's simulated points (the amortized mean and its draws), and its
  Laplace posterior passed the importance check; the answer is its importance-weighted draws. The
  neural training per drive, most of `identify`'s time, is what the amortized estimator saves.
* ``identify``: `vdsbi.api.identify` on the drive, with the platform's effects; its folder stays
  for `predict` and `export`.

The amortized check's simulations also serve the fit: its best point is the fit's start and the
noise measured there weighs the fit's channels, so the fit simulates no candidates of its own. A
fit only places the next check's proposal: that check's likelihood has the noise re-measured at
the fit, so a fit short of the reweighted optimum is corrected by the importance weights, and k̂
says when it cannot be. Each fit is therefore one pass, checked; a failed check is followed by a
reweighting pass from that fit (checked again), up to `FITS` fits, before `identify`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import socket
import time
import traceback
from pathlib import Path

import jax
import numpy as np

from ..estimation import PRIOR_Z_STD, FitRequest, ModelError, fit_likelihood
from ..io import InputError, write_atomically, write_text_atomically
from ..runtime import release_compiled_programs
from ._amortized import PlatformEstimator, Proposal, drive_proposal
from ._check import CheckResult, importance_check, k_threshold, weighted_summary
from ._manifest import Drive
from ._platform import WINDOW_SECONDS, Platform, drive_problem
from ._shape import fixed_shape, length_bucket
from ._windows import drive_x

#: Spread of the t proposal over the amortized posterior (crude: wide) and over the fit's Laplace
#: posterior (its own curvature: near the target).
AMORTIZED_SPREAD, FIT_SPREAD = 1.5, 1.2
#: Points the amortized check simulates (its k̂ threshold is that of its fewer weighted draws:
#: 0.42 for 10 parameters): its simulations mostly place the fit's start and measure the noise
#: that weighs the fit. The check of the fit keeps `_check.DRAWS`: its draws are the answer.
AMORTIZED_DRAWS = 64
#: Fits tried before `identify`, each from the last with the noise re-measured at it, each checked.
FITS = 2


@dataclasses.dataclass(frozen=True)
class Escalation:
    """`identify`'s settings for the drives whose check fails (its own defaults: 2 rounds of 1000).

    Attributes:
        rounds, sims, epochs, ppc_draws: as `vdsbi.api.identify`'s.
    """

    rounds: int = 2
    sims: int = 1000
    epochs: int | None = None
    ppc_draws: int = 100


#: Estimators a worker has loaded, by folder: loaded once per worker, not once per drive.
_LOADED: dict[str, PlatformEstimator] = {}


def _estimator(folder: Path, platform: Platform) -> PlatformEstimator:
    key = f"{folder}:{platform.ident}"
    if key not in _LOADED:
        _LOADED[key] = PlatformEstimator.load(folder, platform)
    return _LOADED[key]


def drive_folder(out: Path, drive: Drive) -> Path:
    return out / "drives" / drive.key


def answer_drive(
    drive: Drive,
    prepared: tuple[Platform | None, Path | None, str | None],
    *,
    out: Path,
    seed: int,
    escalation: Escalation,
    settings_id: str,
    draws_per_window: int = 400,
) -> dict:
    """Answer `drive` and write its result.json (atomically; the record returned). `prepared` is
    the platform, its estimator's folder and why there is none. Bad input is a failed record,
    never an exception: one drive's fault does not stop the fleet."""
    # A worker answers drive after drive in one process: it stays under the memory-map limit.
    release_compiled_programs()
    folder = drive_folder(out, drive)
    folder.mkdir(parents=True, exist_ok=True)
    attempt = _mark_running(folder)
    platform = prepared[0]
    # Keyed by what the manifest says (car and recording), not where the files lie: the same
    # manifest answers alike from any folder.
    own = int(hashlib.sha1(f"{drive.car}\n{drive.name}".encode()).hexdigest()[:8], 16)
    key = jax.random.fold_in(jax.random.key(seed), own % (2**31))
    record = {
        "car": drive.car,
        "recording": drive.name,
        "time": drive.time,
        "order": drive.order,
        "line": drive.line,
        "key": drive.key,
        "platform": None if platform is None else platform.ident,
        "settings": settings_id,
        "attempt": attempt,
        "worker": {"pid": os.getpid(), "host": socket.gethostname()},
    }
    start, cpu = time.perf_counter(), time.process_time()
    stages: dict[str, float] = {}
    try:
        record |= _answer(key, drive, prepared, folder, escalation, draws_per_window, stages)
    except InputError as err:
        record |= {"method": "failed", "error": str(err)}
    except Exception as err:  # a bug or an unforeseen recording: recorded, the fleet goes on
        record |= {
            "method": "failed",
            "error": f"{type(err).__name__}: {err}",
            "traceback": traceback.format_exc(),
        }
    record["seconds"] = round(time.perf_counter() - start, 2)
    # The worker's own processor time: on a shared machine, what the drive cost apart from waiting.
    record["cpu_seconds"] = round(time.process_time() - cpu, 2)
    record["stages"] = {k: round(v, 2) for k, v in stages.items()}
    write_text_atomically(folder / "result.json", json.dumps(record, indent=1) + "\n")
    (folder / "running.json").unlink(missing_ok=True)
    return record


def _mark_running(folder: Path) -> int:
    """Write running.json (this worker's pid and host, the attempt); return the attempt number (a
    killed worker's drive is retried: its running.json is still there)."""
    marker = folder / "running.json"
    attempt = 1
    if marker.exists():
        try:
            attempt = int(json.loads(marker.read_text()).get("attempt", 0)) + 1
        except (ValueError, OSError):
            attempt = 2
    info = {"pid": os.getpid(), "host": socket.gethostname(), "attempt": attempt, "started": time.time()}
    write_text_atomically(marker, json.dumps(info) + "\n")
    return attempt


def _timed(stages: dict, name: str, fn, *args, **kwargs):
    t = time.perf_counter()
    try:
        return fn(*args, **kwargs)
    finally:
        stages[name] = stages.get(name, 0.0) + time.perf_counter() - t


def _answer(key, drive, prepared, folder, escalation, draws_per_window, stages) -> dict:
    """The drive's record from the first level whose check passes (module docstring)."""
    platform, est_folder, no_estimator = prepared
    k_prop, k_check, k_fit_check = jax.random.split(key, 3)
    problem, why = _shaped_problem(drive, platform, no_estimator, stages)
    if why is not None:
        return _identify(drive, platform, folder, escalation, why, stages, problem)
    estimator = _timed(stages, "load", _estimator, est_folder, platform)
    x, has = drive_x(problem)
    try:
        proposal = _timed(stages, "amortized", drive_proposal, k_prop, estimator, x, has, draws_per_window)
    except np.linalg.LinAlgError as err:  # the estimator's draws have no finite spread
        return _identify(drive, platform, folder, escalation, f"no amortized answer ({err})", stages, problem)
    check = _timed(
        stages,
        "check",
        importance_check,
        k_check,
        problem,
        platform.box,
        platform.effects,
        proposal,
        spread=AMORTIZED_SPREAD,
        draws=AMORTIZED_DRAWS,
    )
    checks = {"amortized": _check_record(check)}
    if check.passed:
        return _checked("amortized", check, platform.box, checks, folder)
    check = _fits(k_fit_check, problem, platform, check, checks, stages)
    if check.passed:
        return _checked("amortized+fit", check, platform.box, checks, folder)
    why = (
        f"importance check failed after the fit: k̂ {check.k_hat:.2f} > {k_threshold(len(check.weights)):.2f}"
    )
    return _identify(drive, platform, folder, escalation, why, stages, problem) | {"checks": checks}


def _shaped_problem(drive, platform, no_estimator, stages) -> tuple:
    """(the drive's problem at the estimator's fixed shape, None), or (the problem or None, why
    the amortized path cannot take it)."""
    if no_estimator is not None:
        return None, no_estimator
    problem = _timed(stages, "problem", drive_problem, drive.recording, drive.vehicle)
    why = platform.fits(problem)
    if why is not None:
        return problem, why
    try:
        return fixed_shape(problem, length_bucket(problem, WINDOW_SECONDS)), None
    except InputError as err:
        return problem, err.detail


def _fits(key, problem, platform, check: CheckResult, checks: dict, stages) -> CheckResult:
    """Likelihood fits from the amortized check's best point, each checked, until one passes or
    `FITS` are spent (each check's record added to `checks`); the last check."""
    start, noise = check.best, check.noise
    # Every parameter the model can feel (one the channels do not depend on has a zero Jacobian
    # column and keeps the prior; one the fit's path makes informative is fitted, where probes at
    # one point would miss it): the same set, and so one compiled fit, for every drive.
    free = fitted_parameters(platform)
    for attempt in range(FITS):
        request = FitRequest(free=free, noise=ModelError(start=noise, passes=0), width=len(free))
        fit = _timed(
            stages, "fit", fit_likelihood, problem, start, platform.box, request, effects=platform.effects
        )
        check = _timed(
            stages,
            "check",
            importance_check,
            jax.random.fold_in(key, attempt),
            problem,
            platform.box,
            platform.effects,
            _laplace(fit, platform.box),
            spread=FIT_SPREAD,
            noise=fit.noise,
        )
        checks["fit" if attempt == 0 else f"fit{attempt + 1}"] = _check_record(check)
        if check.passed:
            break
        # The next fit from this one, weighted by the noise measured at it (a reweighting pass).
        start, noise = fit.theta, fit.noise
    return check


#: Parameters a model driven by the measured speed has no use for: its tyres roll freely, so
#: the longitudinal slip stiffnesses act nowhere (`vdsbi.simulator.SpeedDriven`).
NO_EFFECT = {"speed": ("C_kappa_f", "C_kappa_r")}


def fitted_parameters(platform: Platform) -> tuple[str, ...]:
    """The parameters a drive's likelihood fit moves: all but those the platform's model has no
    use for (their Jacobian columns would be zeros, each as costly as a parameter's)."""
    return tuple(n for n in platform.box.names if n not in NO_EFFECT.get(platform.longitudinal, ()))


def _laplace(fit, box) -> Proposal:
    """The fit's Laplace posterior with its own curvature (the quadratic model of the cost the
    check's likelihood is: the fit's noise model, no widening), the prior's variance for the
    parameters not fitted."""
    cov = np.diag(np.full(box.dim, PRIOR_Z_STD**2))
    idx = [box.names.index(n) for n in fit.free]
    if idx:
        cov[np.ix_(idx, idx)] = np.linalg.inv(np.asarray(fit.curvature))
    return Proposal(np.asarray(fit.z, float), cov, 0)


def _check_record(check: CheckResult) -> dict:
    return {
        "k_hat": round(check.k_hat, 3) if np.isfinite(check.k_hat) else None,
        "ess": round(check.ess, 4),
        "noise_ratio": check.noise_ratio,
        "failed_share": round(check.failed_share, 4),
    }


#: The weighted draws of a drive answered by a check (not `identify`: its folder has its own).
DRAWS_FILE = "draws.npz"


def _checked(method: str, check: CheckResult, box, checks: dict, folder: Path) -> dict:
    """The record of a drive answered by a passed check; its weighted draws and the noise model of
    the check's likelihood are written to `DRAWS_FILE` (what predicting other driving needs)."""
    noise = check.noise
    write_atomically(
        folder / DRAWS_FILE,
        lambda tmp: np.savez(
            tmp,
            names=np.asarray(box.names),
            theta=check.theta,
            weights=check.weights,
            channels=np.asarray(noise.channels),
            noise_scale=np.asarray(noise.scale, float),
            noise_tau=np.asarray(noise.tau, float),
        ),
    )
    return {
        "method": method,
        "parameters": weighted_summary(check.theta, check.weights, box, check.informed),
        "checks": checks,
        "noise_ratio": check.noise_ratio,
    }


def _identify(
    drive: Drive, platform, folder: Path, escalation: Escalation, why: str, stages, problem
) -> dict:
    """The full `identify` into the drive's folder (kept for `predict` and `export`), reading the
    drive as the fleet read it (`problem`: following the measured speed where it has one; a
    recording's commanded torques need not move the model as the car moved)."""
    from .. import api

    if problem is None:
        try:
            problem = drive_problem(drive.recording, drive.vehicle)
        except InputError:
            problem = None  # identify says what is wrong with the drive
    mode = "auto" if problem is None else problem.longitudinal
    target = folder / "identify"
    resume = target.exists() and any(target.iterdir())
    res = _timed(
        stages,
        "identify",
        api.identify,
        str(drive.recording),
        str(drive.vehicle),
        api.IdentifyOptions(
            drive=api.DriveOptions(holdout=0.0, longitudinal=mode),
            model=api.ModelOptions(effects=None if platform is None else tuple(platform.effects)),
            budget=api.Budget(
                rounds=escalation.rounds,
                sims=escalation.sims,
                epochs=escalation.epochs,
                ppc_draws=escalation.ppc_draws,
            ),
        ),
        out_dir=target,
        resume=resume,
    )
    params = {}
    for name, p in res.summary["parameters"].items():
        params[name] = {
            "estimate": float(p["estimate"]),
            "mean": float(p.get("mean", p["q50"])),
            "std": float(p["std"]),
            "q05": float(p["q05"]),
            "q50": float(p["q50"]),
            "q95": float(p["q95"]),
            "identified": p.get("identified") is not False,
        }
    ratio = {
        c: round(float(v["model_error_ratio"]), 3) for c, v in res.summary.get("noise_model", {}).items()
    }
    return {"method": "identify", "escalated_because": why, "parameters": params, "noise_ratio": ratio}
