"""`identify`: a posterior over θ from one recording, checkpointed per round; `sample` from the
estimator it saved."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..io import InputError
from ..io._errors import SimulationError
from ._outputs import (
    CHECKPOINT,
    ESTIMATOR,
    RUN_FILE,
    checkpoint_dir,
    summarise,
    write_outputs,
    write_text_atomically,
)
from ._prepare import Problem, prepare
from ._progress import Progress


@dataclasses.dataclass
class IdentifyResult:
    """What `identify` found.

    Attributes:
        posterior: the trained `vdsbi.inference.Posterior` at the recording.
        samples: (num_samples, 6) posterior draws, PARAM_NAMES order.
        summary: the content of posterior.json (parameters, channels, segment, noise, settings).
        out_dir: where the files were written, or None.
    """

    posterior: Any
    samples: np.ndarray
    summary: dict[str, Any]
    out_dir: Path | None = None

    def table(self) -> str:
        """Per-parameter mean, std and 5/50/95 % quantiles as aligned text."""
        rows = [f"{'param':<10} {'mean':>11} {'std':>10} {'q05':>11} {'q50':>11} {'q95':>11}"]
        for name, p in self.summary["parameters"].items():
            rows.append(
                f"{name:<10} {p['mean']:>11.4g} {p['std']:>10.3g} "
                f"{p['q05']:>11.4g} {p['q50']:>11.4g} {p['q95']:>11.4g}"
            )
        return "\n".join(rows)

    def to_json(self) -> str:
        return json.dumps(self.summary, indent=2)


def identify(
    recording,
    vehicle,
    *,
    rounds: int = 2,
    sims: int = 1000,
    embedding: str = "stats",
    seed: int = 0,
    out_dir: str | os.PathLike | None = None,
    resume: bool = False,
    epochs: int | None = None,
    num_samples: int = 1000,
    segment: tuple[float, float] | None = None,
    max_duration: float = 20.0,
    ppc_draws: int = 100,
    progress: bool = False,
    rate: float = 200.0,
    on_round_end: Callable | None = None,
    log: Callable[[str], None] | None = None,
) -> IdentifyResult:
    """Posterior over θ = PARAM_NAMES from one recording (the engine behind `vdsbi identify`).

    Args:
        recording: path (.csv, .parquet, bag) or a `vdsbi.io.Recording`.
        vehicle: path (.json/.yaml) or a `vdsbi.simulator.Vehicle`.
        rounds, sims: APT rounds and simulations per round.
        embedding: "stats" or "cnn".
        seed: the only source of randomness; same seed, same machine → identical samples.
        out_dir: write posterior.json, samples.csv, pairplot.png, ppc.png, estimator.npz and the
            per-round checkpoint here (None: write nothing).
        resume: continue from `out_dir`'s checkpoint (must have been made with the same settings).
        epochs: maximum training epochs per round (default: IdentifySettings' 40).
        num_samples: posterior samples kept.
        segment: (t0, t1) s to use; default the most excited usable stretch of <= max_duration s.
        ppc_draws: posterior draws simulated for the predictive check.
        progress: tqdm bars.
        on_round_end: extra hook called with the APT state after each round's checkpoint.
        log: where one-line messages go (default: nowhere).

    Raises:
        InputError: bad recording, vehicle, settings, a non-empty `out_dir` without `resume`, or
            a window in which almost every simulation fails.
    """
    import jax

    say = log or (lambda s: None)
    rec, veh = _load(recording, vehicle, rate)
    settings = _settings(rounds, sims, embedding, epochs, num_samples)
    if max_duration <= 0:
        raise InputError("settings", "--max-duration", "must be > 0")
    prob = prepare(rec, veh, segment=segment, max_duration=max_duration)
    run_info = _run_info(rec, prob, settings, seed)
    _describe(prob, say)
    sim = prob.simulator()
    k_id, k_ppc = jax.random.split(jax.random.key(int(seed)))
    working = contextlib.nullcontext() if out_dir is None else checkpoint_dir(out_dir, resume=resume)
    with working as out:
        state = None if out is None else _start(out, run_info, resume, say)
        posterior, samples, state = _train(k_id, prob, sim, settings, state, out, progress, on_round_end, say)
        summary = _summary(prob, samples, state, run_info)
        ppc = posterior_predictive(k_ppc, sim, samples, ppc_draws)
        summary["ppc"] = _ppc_summary(prob, ppc)
        result = IdentifyResult(posterior, samples, summary, out)
        if out is not None:
            write_outputs(out, result, prob, ppc)
    return result


def _load(recording, vehicle, rate: float):
    """(Recording, Vehicle) from paths or objects, cross-checked when both are files."""
    from ..io import load_drive, read_recording, read_vehicle

    if isinstance(recording, (str, os.PathLike)) and isinstance(vehicle, (str, os.PathLike)):
        return load_drive(recording, vehicle, rate=rate)
    rec = read_recording(recording, rate=rate) if isinstance(recording, (str, os.PathLike)) else recording
    veh = read_vehicle(vehicle) if isinstance(vehicle, (str, os.PathLike)) else vehicle
    return rec, veh


def _settings(rounds, sims, embedding, epochs, num_samples):
    """`IdentifySettings` (which checks them) with `epochs` as the training's epoch limit."""
    from ..inference import IdentifySettings

    base = IdentifySettings()
    cfg = base.config if epochs is None else dataclasses.replace(base.config, max_epochs=int(epochs))
    return IdentifySettings(
        rounds=int(rounds),
        sims_per_round=int(sims),
        embedding=embedding,
        num_samples=int(num_samples),
        config=cfg,
    )


def _run_info(rec, prob: Problem, settings, seed: int) -> dict[str, Any]:
    """What run.json records: a checkpoint resumes only a run with the same."""
    return {
        "recording": str(rec.source),
        "seed": int(seed),
        "settings": json.loads(json.dumps(dataclasses.asdict(settings), default=str)),
        "segment": [prob.segment["t0"], prob.segment["t1"]],
        "channels": list(prob.channels),
        "rate_hz": rec.rate,
    }


def _describe(prob: Problem, say: Callable[[str], None]) -> None:
    seg = prob.segment
    say(f"segment {seg['t0']:.2f} .. {seg['t1']:.2f} s ({seg['how']}); channels {', '.join(prob.channels)}")
    estimated = any(s.startswith("estimated") for s in prob.noise_source.values())
    say(
        "noise std "
        + ", ".join(f"{c} {v:.3g}" for c, v in prob.noise_std.items())
        + (" (estimated)" if estimated else " (vehicle file)")
    )


def _start(out: Path, run_info: dict, resume: bool, say: Callable[[str], None]):
    """The checkpointed state to resume from (None: start afresh); writes run.json."""
    from ..inference import load_state

    state = None
    if resume and (out / CHECKPOINT).exists():
        saved = json.loads((out / RUN_FILE).read_text())
        if saved != run_info:
            diff = [k for k in run_info if saved.get(k) != run_info[k]]
            raise InputError(out / RUN_FILE, ", ".join(diff), "differs from this run's; cannot resume")
        state = load_state(out / CHECKPOINT)
        say(f"resuming after round {state.round} of {run_info['settings']['rounds']}")
    write_text_atomically(out / RUN_FILE, json.dumps(run_info, indent=2) + "\n")
    return state


def _train(key, prob: Problem, sim, settings, state, out, progress, on_round_end, say):
    """`vdsbi.inference.identify` with progress bars, per-round checkpoints and messages."""
    from ..inference import identify as npe_identify, save_state

    bars = Progress(settings.rounds, progress)

    def round_end(st):
        if out is not None:
            save_state(out / CHECKPOINT, st)
        bars.round_end(st)
        h = st.history[-1]
        say(
            f"round {st.round}/{settings.rounds}: {h.get('num_used')} simulations used, "
            f"{h.get('epochs', '?')} epochs, best val loss {h.get('best_val_loss', float('nan')):.4g}"
            + (" (checkpoint saved)" if out is not None else "")
        )
        if on_round_end is not None:
            on_round_end(st)

    readings = prob.rec.measured(prob.channels)
    try:
        return npe_identify(
            key,
            sim,
            prob.prior(),
            readings,
            settings,
            on_round_end=round_end,
            on_epoch_end=bars.epoch,
            on_simulate=bars.simulate,
            state=state,
        )
    except SimulationError as err:
        # A property of this recording, not a bug: say so in one line.
        raise InputError(
            prob.rec.source,
            "segment",
            f"almost every simulation of this window failed ({err}); check the time base, "
            "units of the torques and that the car keeps rolling in the window",
        ) from None
    finally:
        bars.close()


def _summary(prob: Problem, samples: np.ndarray, state, run_info: dict) -> dict[str, Any]:
    """posterior.json without its predictive check."""
    return {
        "vdsbi_version": __version__,
        "recording": run_info["recording"],
        "parameters": summarise(samples, prob.vehicle.default_prior()),
        "channels": list(prob.channels),
        "segment": prob.segment,
        "noise_std": prob.noise_std,
        "noise_source": prob.noise_source,
        "v0_range": list(prob.v0_range),
        "seed": run_info["seed"],
        "settings": run_info["settings"],
        "rounds": [{k: v for k, v in h.items() if isinstance(v, (int, float, str))} for h in state.history],
    }


def posterior_predictive(key, sim, samples: np.ndarray, n: int) -> dict[str, np.ndarray]:
    """Simulate `n` posterior draws (with sensor noise); 5/50/95 % bands per sample and channel."""
    import jax.numpy as jnp

    n = min(n, samples.shape[0])
    ys, ok = sim(key, jnp.asarray(samples[:n], jnp.float32))
    ys = np.asarray(ys)[np.asarray(ok)]
    q = np.quantile(ys, [0.05, 0.5, 0.95], axis=0) if ys.shape[0] else np.full((3, *ys.shape[1:]), np.nan)
    return {"q05": q[0], "q50": q[1], "q95": q[2], "n": ys.shape[0]}


def _ppc_summary(prob: Problem, ppc: dict[str, np.ndarray]) -> dict[str, Any]:
    obs = prob.rec.measured(prob.channels)
    inside = (obs >= ppc["q05"]) & (obs <= ppc["q95"])
    return {
        "draws": int(ppc["n"]),
        # None when no posterior draw simulated successfully (no band to compare with).
        "fraction_inside_90pct_band": {
            c: (float(inside[:, i].mean()) if ppc["n"] else None) for i, c in enumerate(prob.channels)
        },
    }


def sample(run_dir: str | os.PathLike, n: int, *, seed: int = 0):
    """`n` draws from the estimator `identify` saved in `run_dir`, as a DataFrame (one column per
    parameter).

    Raises:
        InputError: no readable estimator in `run_dir`, or `n` < 1.
    """
    import jax
    import pandas as pd

    from ..inference import Posterior
    from ..simulator import PARAM_NAMES

    path = Path(run_dir) / ESTIMATOR
    if not path.is_file():
        raise InputError(path, "DIR", "no estimator here; run `vdsbi identify` first")
    if n < 1:
        raise InputError("settings", "--n", f"must be >= 1, got {n}")
    try:
        post = Posterior.load(path)
    except Exception as err:  # corrupt or foreign file
        raise InputError(path, "estimator", f"cannot be read ({type(err).__name__}: {err})") from None
    samples = np.asarray(post.sample(jax.random.key(seed), n))
    return pd.DataFrame(samples, columns=list(post.prior.names or PARAM_NAMES))
