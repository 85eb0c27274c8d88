"""Python API mirroring the CLI: `identify`, `simulate`, `diagnose`, `observability`.

Each function takes paths or in-memory objects and returns a result object; `identify` with
`out_dir` writes exactly what `vdsbi identify` writes (the CLI is a thin shell around it).

    from vdsbi import api
    res = api.identify("drive.csv", "vehicle.json", rounds=2, sims=1000, seed=0)
    print(res.table())
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__
from .io._errors import InputError

#: Files `identify` writes into its output directory.
CHECKPOINT = "checkpoint.npz"
RUN_FILE = "run.json"
ESTIMATOR = "estimator.npz"


# --------------------------------------------------------------------------------------------
# Problem set-up: segment, channels, noise, initial speed
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass
class Problem:
    """A recording prepared for identification (the chosen segment and its noise model)."""

    rec: Any  # vdsbi.io.Recording, sliced to the segment
    vehicle: Any
    channels: tuple[str, ...]
    segment: dict[str, Any]
    noise_std: dict[str, float]
    noise_source: dict[str, str]
    v0_range: tuple[float, float]

    def simulator(self):
        import jax.numpy as jnp

        from .simulator import CHANNELS, SensorNoise, StochasticSimulator, make_model

        add = jnp.array([self.noise_std.get(c, 0.0) for c in CHANNELS])
        noise = SensorNoise(jnp.zeros(len(CHANNELS)), add)
        return StochasticSimulator(
            make_model(self.vehicle), self.rec.inputs(), self.channels, self.v0_range, noise
        )

    def prior(self):
        from .inference import BoxPrior
        from .simulator import PARAM_NAMES

        box = self.vehicle.default_prior()
        return BoxPrior([box[n][0] for n in PARAM_NAMES], [box[n][1] for n in PARAM_NAMES], names=PARAM_NAMES)


def _excitation_score(rec) -> float:
    # Same normalisation as find_segments' thresholds: 0.005 rad steer std, 100 N·m torque std.
    return float(np.std(rec.steer) / 0.005 + np.std(rec.torque_front + rec.torque_rear) / 100.0)


def _quiet_start(rec, a: float, b: float, search: float = 3.0) -> float:
    """Move the window start to where the car is laterally near rest.

    The simulator starts with V_y = r = 0 (the contract: "assumed at rest laterally"), so a
    window that begins mid-corner starts with a built-in mismatch. Within the first
    `search` s, take the first sample with small yaw rate and steer if there is one.
    """
    if "yaw_rate" not in rec.channels:
        return a
    t = rec.t
    sel = (t >= a) & (t <= min(a + search, b - 5.0))
    ok = sel & (np.abs(rec.channels["yaw_rate"]) < 0.03) & (np.abs(rec.steer) < 0.02)
    return float(t[np.argmax(ok)]) if ok.any() else a


def choose_segment(
    rec, vehicle, *, segment: tuple[float, float] | None = None, max_duration: float = 20.0
) -> tuple[Any, dict[str, Any]]:
    """The stretch of `rec` to identify from, and a description of the choice.

    With `segment` the user's [t0, t1] is taken as is. Otherwise the usable stretches from
    `vdsbi.io.find_segments` are considered, and the window of at most `max_duration` s (1 s steps)
    with the most input excitation is taken.

    Raises:
        InputError: no usable stretch, or a `segment` outside the recording.
    """
    from .io import find_segments

    if segment is not None:
        t0, t1 = segment
        if not (rec.t[0] - 1e-9 <= t0 < t1 <= rec.t[-1] + 1e-9):
            raise InputError(
                rec.source,
                "--segment",
                f"[{t0}, {t1}] s is not inside the recording [{rec.t[0]:.3f}, {rec.t[-1]:.3f}] s",
            )
        return rec.slice(t0, t1), {"t0": t0, "t1": t1, "how": "given by the user", "usable": None}
    min_dur = min(5.0, 0.9 * rec.duration)
    segs = find_segments(rec, wheel_radius=vehicle.wheel_radius, min_duration=min_dur)
    usable = [s for s in segs if s.usable]
    described = {
        "usable": [[round(s.t0, 3), round(s.t1, 3)] for s in usable],
        "rejected": [[round(s.t0, 3), round(s.t1, 3), s.reason] for s in segs if not s.usable],
    }
    if not usable:
        reasons = "; ".join(f"{s.t0:.1f}-{s.t1:.1f} s: {s.reason}" for s in segs[:4])
        raise InputError(rec.source, "segment", f"no usable stretch for the model ({reasons})")
    best, best_score = None, -np.inf
    for s in usable:
        if s.duration <= max_duration:
            starts = [s.t0]
        else:
            starts = list(np.arange(s.t0, s.t1 - max_duration + 1e-9, 1.0))
        for a in starts:
            b = min(a + max_duration, s.t1)
            score = _excitation_score(rec.slice(a, b)) * (b - a)
            if score > best_score:
                best, best_score = (float(a), float(b)), score
    a, b = best
    a = _quiet_start(rec, a, b)
    how = (
        "whole recording"
        if (a <= rec.t[0] + 1e-6 and b >= rec.t[-1] - 1e-6)
        else (f"most excited window of <= {max_duration:g} s among {len(usable)} usable stretch(es)")
    )
    return rec.slice(a, b), {"t0": a, "t1": b, "how": how, **described}


def prepare(
    rec, vehicle, *, segment: tuple[float, float] | None = None, max_duration: float = 20.0
) -> Problem:
    """Segment, channels (all measured, >= 2), additive noise and initial-speed range."""
    from .io import estimate_noise_std

    seg_rec, seg = choose_segment(rec, vehicle, segment=segment, max_duration=max_duration)
    from .simulator import CHANNELS

    channels = tuple(c for c in CHANNELS if c in seg_rec.channels)
    if len(channels) < 2:
        raise InputError(rec.source, "channels", f"need at least 2 measured channels, found {list(channels)}")
    est = estimate_noise_std(seg_rec)
    noise, source = {}, {}
    for c in channels:
        if c in vehicle.noise_std:
            noise[c], source[c] = float(vehicle.noise_std[c]), "vehicle file"
        else:
            noise[c], source[c] = float(est[c]), "estimated from the recording"
    speed = seg_rec.speed(vehicle.wheel_radius)
    n0 = max(1, int(round(0.1 * seg_rec.rate)))
    v0 = float(np.mean(speed[:n0]))
    margin = 0.2 + 0.02 * v0
    return Problem(seg_rec, vehicle, channels, seg, noise, source, (max(0.5, v0 - margin), v0 + margin))


# --------------------------------------------------------------------------------------------
# Progress
# --------------------------------------------------------------------------------------------


class _Progress:
    """tqdm bars per round: simulations, then training epochs with the validation loss."""

    def __init__(self, rounds: int, enabled: bool):
        self.rounds, self.enabled, self.bar = rounds, enabled, None

    def _close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def simulate(self, n: int):
        if not self.enabled:
            return
        from tqdm.auto import tqdm

        self._close()
        self.r = getattr(self, "r", -1) + 1
        self.bar = tqdm(total=n, desc=f"round {self.r + 1}/{self.rounds} simulate", unit="sim", leave=True)

    def simulated(self):
        if self.enabled and self.bar is not None:
            self.bar.update(self.bar.total - self.bar.n)
            self._close()

    def epoch(self, r, epoch, train_loss, val_loss):
        if not self.enabled:
            return
        from tqdm.auto import tqdm

        if self.bar is not None and self.bar.desc.endswith("simulate"):
            self.simulated()
        if self.bar is None:
            self.bar = tqdm(desc=f"round {r + 1}/{self.rounds} train", unit="epoch", leave=True)
        self.bar.update(1)
        self.bar.set_postfix(val_loss=f"{val_loss:.3f}")

    def round_end(self, state):
        self._close()
        self.r = state.round - 1

    def close(self):
        self._close()


# --------------------------------------------------------------------------------------------
# identify
# --------------------------------------------------------------------------------------------


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


def _settings(rounds, sims, embedding, epochs, num_samples):
    from .inference import IdentifySettings

    base = IdentifySettings()
    cfg = base.config if epochs is None else dataclasses.replace(base.config, max_epochs=int(epochs))
    return IdentifySettings(
        rounds=int(rounds),
        sims_per_round=int(sims),
        embedding=embedding,
        num_samples=int(num_samples),
        config=cfg,
    )


def _settings_dict(settings) -> dict:
    d = dataclasses.asdict(settings)
    return json.loads(json.dumps(d, default=str))


def _write_text_atomic(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.chmod(tmp, 0o644)
    os.replace(tmp, path)


def summarise(samples: np.ndarray, prior_box: dict[str, tuple[float, float]]) -> dict[str, dict[str, float]]:
    from .simulator import PARAM_NAMES, PARAM_UNITS

    q = np.quantile(samples, [0.05, 0.5, 0.95], axis=0)
    out = {}
    for i, n in enumerate(PARAM_NAMES):
        out[n] = {
            "mean": float(samples[:, i].mean()),
            "std": float(samples[:, i].std()),
            "q05": float(q[0, i]),
            "q50": float(q[1, i]),
            "q95": float(q[2, i]),
            "unit": PARAM_UNITS[n] if isinstance(PARAM_UNITS, dict) else PARAM_UNITS[i],
            "prior": [float(v) for v in prior_box[n]],
        }
    return out


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
        InputError: bad recording, vehicle, settings, or a non-empty `out_dir` without `resume`.
    """
    import jax

    from .inference import identify as _identify, load_state, save_state
    from .io import load_drive, read_recording, read_vehicle

    say = log or (lambda s: None)
    if isinstance(recording, (str, os.PathLike)) and isinstance(vehicle, (str, os.PathLike)):
        rec, veh = load_drive(recording, vehicle, rate=rate)
    else:
        rec = read_recording(recording, rate=rate) if isinstance(recording, (str, os.PathLike)) else recording
        veh = read_vehicle(vehicle) if isinstance(vehicle, (str, os.PathLike)) else vehicle
    if embedding not in ("stats", "cnn"):
        raise InputError("settings", "--embedding", f"must be 'stats' or 'cnn', got {embedding!r}")
    if rounds < 1 or sims < 10:
        raise InputError("settings", "--rounds/--sims", "need rounds >= 1 and sims >= 10")
    prob = prepare(rec, veh, segment=segment, max_duration=max_duration)
    settings = _settings(rounds, sims, embedding, epochs, num_samples)
    run_info = {
        "recording": str(getattr(rec, "source", recording)),
        "seed": int(seed),
        "settings": _settings_dict(settings),
        "segment": [prob.segment["t0"], prob.segment["t1"]],
        "channels": list(prob.channels),
        "rate_hz": rec.rate,
    }
    say(
        f"segment {prob.segment['t0']:.2f} .. {prob.segment['t1']:.2f} s ({prob.segment['how']}); "
        f"channels {', '.join(prob.channels)}"
    )
    say(
        "noise std "
        + ", ".join(f"{c} {v:.3g}" for c, v in prob.noise_std.items())
        + (
            " (estimated)"
            if any(s.startswith("estimated") for s in prob.noise_source.values())
            else " (vehicle file)"
        )
    )

    out = None if out_dir is None else Path(out_dir)
    created = False
    state = None
    if out is not None:
        if out.exists() and not out.is_dir():
            raise InputError(out, "--out", "exists and is not a directory")
        has = out.exists() and any(out.iterdir())
        if has and not resume:
            raise InputError(out, "--out", "directory exists and is not empty; use --resume or another DIR")
        if resume and (out / CHECKPOINT).exists():
            saved = json.loads((out / RUN_FILE).read_text())
            if saved != run_info:
                diff = [k for k in run_info if saved.get(k) != run_info[k]]
                raise InputError(out / RUN_FILE, ", ".join(diff), "differs from this run's; cannot resume")
            state = load_state(out / CHECKPOINT)
            say(f"resuming after round {state.round} of {rounds}")
        created = not out.exists()
        out.mkdir(parents=True, exist_ok=True)
        _write_text_atomic(out / RUN_FILE, json.dumps(run_info, indent=2) + "\n")

    bars = _Progress(rounds, progress)

    def round_end(st):
        if out is not None:
            save_state(out / CHECKPOINT, st)
        bars.round_end(st)
        h = st.history[-1]
        say(
            f"round {st.round}/{rounds}: {h.get('num_used')} simulations used, "
            f"{h.get('epochs', '?')} epochs, best val loss {h.get('best_val_loss', float('nan')):.4g}"
            + (" (checkpoint saved)" if out is not None else "")
        )
        if on_round_end is not None:
            on_round_end(st)

    def on_sim(n):
        bars.simulate(n)

    sim = prob.simulator()
    prior = prob.prior()
    key = jax.random.key(int(seed))
    k_id, k_ppc = jax.random.split(key)
    try:
        if state is not None and state.round >= rounds:
            # Already finished: rebuild the posterior from the final checkpoint.

            posterior, samples, _ = _identify(
                k_id, sim, prior, prob.rec.measured(prob.channels), settings, state=state
            )
        else:
            posterior, samples, state = _identify(
                k_id,
                sim,
                prior,
                prob.rec.measured(prob.channels),
                settings,
                on_round_end=round_end,
                on_epoch_end=bars.epoch,
                on_simulate=on_sim,
                state=state,
            )
    except BaseException as err:
        bars.close()
        if out is not None and created and not (out / CHECKPOINT).exists():
            shutil.rmtree(out, ignore_errors=True)
        if isinstance(err, ValueError) and str(err).startswith("Too few simulations"):
            # Every draw left the model's domain (car stopped or reversed, non-finite): that
            # is a property of this recording, not a bug — say so in one line.
            raise InputError(
                prob.rec.source,
                "segment",
                f"almost every simulation of this window failed ({err}); check the time base, "
                "units of the torques and that the car keeps rolling in the window",
            ) from None
        raise
    bars.close()

    box = veh.default_prior()
    summary: dict[str, Any] = {
        "vdsbi_version": __version__,
        "recording": run_info["recording"],
        "parameters": summarise(samples, box),
        "channels": list(prob.channels),
        "segment": prob.segment,
        "noise_std": prob.noise_std,
        "noise_source": prob.noise_source,
        "v0_range": list(prob.v0_range),
        "seed": int(seed),
        "settings": run_info["settings"],
        "rounds": [{k: v for k, v in h.items() if isinstance(v, (int, float, str))} for h in state.history],
    }
    ppc = posterior_predictive(k_ppc, sim, samples, ppc_draws)
    obs = prob.rec.measured(prob.channels)
    inside = (obs >= ppc["q05"]) & (obs <= ppc["q95"])
    summary["ppc"] = {
        "draws": int(ppc["n"]),
        # None when no posterior draw simulated successfully (no band to compare with).
        "fraction_inside_90pct_band": {
            c: (float(inside[:, i].mean()) if ppc["n"] else None) for i, c in enumerate(prob.channels)
        },
    }
    result = IdentifyResult(posterior, samples, summary, out)
    if out is not None:
        write_outputs(out, result, prob, ppc)
    return result


def posterior_predictive(key, sim, samples: np.ndarray, n: int) -> dict[str, np.ndarray]:
    """Simulate `n` posterior draws (with sensor noise); 5/50/95 % bands per sample and channel."""
    import jax.numpy as jnp

    n = min(n, samples.shape[0])
    ys, ok = sim(key, jnp.asarray(samples[:n], jnp.float32))
    ys = np.asarray(ys)[np.asarray(ok)]
    q = np.quantile(ys, [0.05, 0.5, 0.95], axis=0) if ys.shape[0] else np.full((3, *ys.shape[1:]), np.nan)
    return {"q05": q[0], "q50": q[1], "q95": q[2], "n": ys.shape[0]}


def write_outputs(out: Path, result: IdentifyResult, prob: Problem, ppc) -> None:
    import pandas as pd

    from .simulator import PARAM_NAMES

    tmp = Path(tempfile.mkdtemp(prefix=".outputs-", dir=out))
    try:
        pd.DataFrame(result.samples, columns=list(PARAM_NAMES)).to_csv(
            tmp / "samples.csv", index=False, float_format="%.9g"
        )
        (tmp / "posterior.json").write_text(result.to_json() + "\n")
        result.posterior.save(tmp / ESTIMATOR)
        pairplot(result.samples, list(PARAM_NAMES), tmp / "pairplot.png")
        ppc_plot(prob, ppc, tmp / "ppc.png")
        for f in tmp.iterdir():
            os.replace(f, out / f.name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def pairplot(samples: np.ndarray, labels: Sequence[str], path: Path, truth: np.ndarray | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = samples.shape[1]
    fig, axes = plt.subplots(d, d, figsize=(2.0 * d, 2.0 * d))
    for i in range(d):
        for j in range(d):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                continue
            if i == j:
                ax.hist(samples[:, i], bins=40, color="C0", alpha=0.8)
                if truth is not None:
                    ax.axvline(truth[i], color="r")
            else:
                ax.scatter(samples[:, j], samples[:, i], s=1, alpha=0.3, color="C0")
                if truth is not None:
                    ax.plot(truth[j], truth[i], "r+", ms=10)
            if i == d - 1:
                ax.set_xlabel(labels[j])
            if j == 0 and i > 0:
                ax.set_ylabel(labels[i])
            ax.tick_params(labelsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def ppc_plot(prob: Problem, ppc, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = prob.rec.t
    obs = prob.rec.measured(prob.channels)
    c = len(prob.channels)
    fig, axes = plt.subplots(c, 1, figsize=(9, 1.8 * c), sharex=True)
    axes = np.atleast_1d(axes)
    for i, name in enumerate(prob.channels):
        ax = axes[i]
        ax.fill_between(
            t, ppc["q05"][:, i], ppc["q95"][:, i], color="C0", alpha=0.3, label="posterior predictive 90 %"
        )
        ax.plot(t, ppc["q50"][:, i], color="C0", lw=1, label="predictive median")
        ax.plot(t, obs[:, i], color="k", lw=0.7, label="recording")
        ax.set_ylabel(name)
    axes[0].legend(loc="upper right", fontsize=7)
    axes[-1].set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


# --------------------------------------------------------------------------------------------
# simulate, diagnose, observability
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass
class SimulateResult:
    """Noise-free readings of one simulation: t (T,), readings (T, 6) in CHANNELS order."""

    t: np.ndarray
    readings: np.ndarray
    ok: bool

    def to_frame(self):
        import pandas as pd

        from .simulator import CHANNELS

        df = pd.DataFrame(self.readings, columns=list(CHANNELS))
        df.insert(0, "t", self.t)
        return df


def simulate(
    theta,
    inputs,
    vehicle=None,
    *,
    v0: float = 10.0,
    effects: Sequence[str] = (),
    effect_params: dict | None = None,
) -> SimulateResult:
    """One noise-free simulation. `theta`: (6,) array or {name: value}; `vehicle`: Vehicle or path."""
    from .io import read_vehicle
    from .simulator import default_vehicle, simulate as _sim, theta_from_dict

    veh = (
        default_vehicle()
        if vehicle is None
        else (read_vehicle(vehicle) if isinstance(vehicle, (str, os.PathLike)) else vehicle)
    )
    th = np.asarray(theta_from_dict(theta) if isinstance(theta, dict) else theta, dtype=float)
    ys, ok = _sim(th, inputs, veh, v0=float(v0), effects=effects, effect_params=effect_params)
    return SimulateResult(np.asarray(inputs.ts), np.asarray(ys), bool(ok))


def diagnose(*args, **kwargs):
    """`vdsbi.discovery.diagnose` (imported lazily; raises ImportError if discovery is absent)."""
    from .discovery import diagnose as _diagnose

    return _diagnose(*args, **kwargs)


def observability(*args, **kwargs):
    """The Fisher-information / CRB report from `vdsbi.diagnostics` (imported lazily)."""
    from . import diagnostics

    for name in ("observability", "crb_report", "fisher_report"):
        fn = getattr(diagnostics, name, None)
        if fn is not None:
            return fn(*args, **kwargs)
    raise ImportError("vdsbi.diagnostics exposes no observability report function")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(0)
