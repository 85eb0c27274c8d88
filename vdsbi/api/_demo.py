"""`demo`: the whole loop on a drive with a concealed effect: identify θ with the base model
(flagged), diagnose the mismatch (names the effect), identify again with it, and a before/after
page, all in one folder."""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from ..io import Recording, output_dir
from ..problem import parameter_name
from ..runtime import in_background
from ._commands import measured_priors
from ._diagnose import diagnose
from ._identify import identify
from ._identify_result import IdentifyResult
from ._options import Budget, IdentifyOptions, ModelOptions, Progress
from ._pages import demo_page
from .outputs import plot_posterior
from .plots import before_after_plot

if TYPE_CHECKING:
    from ..simulator import Vehicle

#: The effect hidden in the demo recording (identify's model does not know it).
CONCEALED = {"sensor_bias": {"ax": 0.3, "ay": -0.25, "yaw_rate": 0.0}}
NOISE_STD = {"ax": 0.05, "ay": 0.05, "yaw_rate": 0.003, "omega_front": 0.1, "omega_rear": 0.1, "vx": 0.03}
#: Initial speed of the demo drive, m/s.
DEMO_V0 = 15.0


@dataclasses.dataclass(frozen=True)
class DemoBudget:
    """How much the demo computes.

    Attributes:
        duration: the drive, s.
        rounds, sims, epochs: APT budget of each identification (epochs None: the default).
        base_rounds: rounds of the base-model identification (its job is to be flagged, and
            one round is enough for that).
        ppc_draws: posterior draws of each identification's predictive band.
        diagnose: options of the diagnosis (`vdsbi.discovery.DiagnoseSettings` fields).
    """

    duration: float = 20.0
    rounds: int = 2
    sims: int = 1000
    epochs: int | None = None
    base_rounds: int = 1
    ppc_draws: int = 100
    diagnose: dict = dataclasses.field(default_factory=dict)


#: --quick: a 10 s drive, 2 x 300 simulations (base model 1 x 300), no diagnosis plots.
QUICK = DemoBudget(duration=10.0, sims=300, diagnose={"plots": False})


@dataclasses.dataclass
class DemoResult:
    """Where the demo wrote its files, what `identify` found with the base model and then with
    the named effects (None when none was named), the diagnosis in one line, and the wall time
    in seconds."""

    out: Path
    identified: IdentifyResult
    diagnosis: str
    seconds: float
    refined: IdentifyResult | None = None


def demo_recording(out: str | os.PathLike, *, duration: float, seed: int) -> dict:
    """Write out/recording.csv, out/vehicle.json and out/truth.json; return the truth.

    The built-in vehicle at the seed's true θ with the `CONCEALED` effect and `NOISE_STD`
    sensor noise, on a random maneuver (deterministic in `seed`) that keeps it rolling.
    """
    import jax
    import numpy as np
    import pandas as pd

    from ..simulator import (
        CHANNELS,
        SEED_TRUE_THETA,
        default_vehicle,
        random_profile,
        simulate,
        theta_from_dict,
    )
    from ..simulator.effects import EffectSettings

    out = Path(out)
    veh = default_vehicle()
    # A random maneuver can brake the car to a stop (the model is not valid at standstill):
    # draw maneuvers until one keeps it rolling, deterministically from `seed`.
    for attempt in range(50):
        inp = random_profile(jax.random.fold_in(jax.random.key(seed), attempt), duration=duration)
        ys, ok = simulate(
            theta_from_dict(SEED_TRUE_THETA),
            inp,
            veh,
            v0=DEMO_V0,
            effects=EffectSettings(enabled=list(CONCEALED), params=CONCEALED),
        )
        if ok and float(np.min(np.asarray(ys)[:, CHANNELS.index("vx")])) > 5.0:
            break
    else:
        raise RuntimeError("demo: no drivable random maneuver found in 50 draws")
    rng = np.random.default_rng(seed)
    df = pd.DataFrame(
        {
            "t": np.asarray(inp.ts),
            "steer": inp.steer,
            "torque_front": inp.torque_front,
            "torque_rear": inp.torque_rear,
        }
    )
    for i, c in enumerate(CHANNELS):
        df[c] = np.asarray(ys)[:, i] + rng.normal(0.0, NOISE_STD[c], len(df))
    df.to_csv(out / "recording.csv", index=False, float_format="%.10g")
    (out / "vehicle.json").write_text(json.dumps({**veh.to_dict(), "noise_std": NOISE_STD}, indent=2) + "\n")
    truth = {
        "theta": dict(SEED_TRUE_THETA),
        "concealed_effect": CONCEALED,
        "v0": DEMO_V0,
        "duration_s": duration,
    }
    (out / "truth.json").write_text(json.dumps(truth, indent=2) + "\n")
    return truth


def demo(
    out: str | os.PathLike | None = None,
    *,
    quick: bool = False,
    seed: int = 0,
    run_diagnosis: bool = True,
    progress: bool = False,
    log: Callable[[str], None] | None = None,
    budget: DemoBudget | None = None,
) -> DemoResult:
    """The whole loop on a drive with a concealed sensor bias, into `out` (default:
    vdsbi-demo-<time>): simulate it (recording.csv, vehicle.json, truth.json); identify θ with the
    base model (identify/, flagged); diagnose (diagnose/, names the effect); identify again with
    the named effect (identify-<effect>/); a before/after page (report.html, before_after.png,
    pairplot_0.png, pairplot_1.png with the truth marked).

    Args:
        quick: `QUICK`'s budget (default `DemoBudget()`: 20 s, 2 x 1000 simulations).
        seed: the drive's and the methods' seed.
        run_diagnosis: diagnose and re-identify after the first identify.
        progress: tqdm bars while identifying.
        log: where progress lines go (default: nowhere).
        budget: overrides `quick`.
    """
    t_start = time.perf_counter()
    name = Path(out or time.strftime("vdsbi-demo-%Y%m%d-%H%M%S"))
    say = log or (lambda s: None)
    b = budget or (QUICK if quick else DemoBudget())
    with output_dir(name) as d:
        say(f"1/5 simulating a {b.duration:g} s drive of the built-in vehicle with a concealed effect")
        truth = demo_recording(d, duration=b.duration, seed=seed)
        rec, veh = _drive(d, name)
        run = functools.partial(_identify, _DemoRun(rec, veh, d, name, b, seed, progress, say))
        if run_diagnosis:
            # The diagnosis does not use the first identification, so it runs alongside it on
            # another thread: each spends much of its time compiling on one core.
            lines: list[str] = []
            diagnosing = in_background(
                _diagnose, rec, veh, d, name, seed=seed, options=b.diagnose, log=lines.append
            )
        say(f"2/5 identify with the base model: {b.base_rounds} round(s) x {b.sims} simulations")
        # Flagged anyway: no point spending more rounds on it.
        base = run("identify", (), rounds=b.base_rounds)
        runs, diagnosis, report = [("base model", "identify", base)], "skipped (--no-diagnose)", None
        if run_diagnosis:
            say("3/5 diagnose: looking for missing physics (run alongside step 2)")
            report = diagnosing.result()
            for line in lines:
                say(line)
            diagnosis = _diagnosis(report)
            if report["identify_command"]:
                say(f"4/5 identify again, as diagnose says: {report['identify_command']}")
                folder = "identify-" + "-".join(report["chosen"])
                refined = run(folder, report["chosen"], priors=_measured(report))
                runs.append((f"with {', '.join(report['chosen'])}", folder, refined))
        say("5/5 the before/after page")
        _before_after(d, truth, runs, report)
        (d / "README.txt").write_text(_readme(b, runs, diagnosis))
    refined = runs[1][2] if len(runs) > 1 else None
    return DemoResult(name.resolve(), base, diagnosis, time.perf_counter() - t_start, refined)


def _names(name: Path, folder: str) -> tuple[Path, Path, Path]:
    """(recording, vehicle, output folder) as the user will find them."""
    return name / "recording.csv", name / "vehicle.json", name / folder


def _diagnose(rec, veh, d: Path, name: Path, *, seed: int, options: dict, log) -> dict:
    """The diagnosis of the demo drive into d/diagnose, its progress lines to `log`; its report."""
    res = diagnose(
        rec, veh, d / "diagnose", names=_names(name, "diagnose"), seed=seed, quiet=False, log=log, **options
    )
    return res.report


@dataclasses.dataclass(frozen=True)
class _DemoRun:
    """What the demo's identifications share: the drive, the working folder ``d`` and the
    folder's name as the user gave it, the budget, the seed and where progress goes."""

    rec: Recording
    veh: Vehicle
    d: Path
    name: Path
    budget: DemoBudget
    seed: int
    progress: bool
    say: Callable[[str], None]


def _identify(run: _DemoRun, folder: str, effects, *, rounds: int | None = None, priors=None):
    """One identification of the demo drive into d/folder with identify's default effects and
    `effects` added (as the command diagnose prints), its table in table.txt; ``rounds``
    defaults to the budget's."""
    from ..inference import StatisticsMLP

    rec, veh, d, name, budget, say = run.rec, run.veh, run.d, run.name, run.budget, run.say
    options = IdentifyOptions(
        model=ModelOptions(add_effects=tuple(effects), priors=priors or {}),
        budget=Budget(
            rounds=budget.rounds if rounds is None else rounds,
            sims=budget.sims,
            epochs=budget.epochs,
            embedding=StatisticsMLP(),
            ppc_draws=budget.ppc_draws,
        ),
        seed=run.seed,
    )
    res = identify(
        rec,
        veh,
        options,
        out_dir=d / folder,
        progress=Progress(say=say, bars=run.progress),
        names=_names(name, folder),
    )
    (d / folder / "table.txt").write_text(res.table() + "\n")
    say(res.table())
    return res


def _measured(report) -> dict:
    """The prior ranges the diagnosis measured (those its printed command passes as --prior)."""
    chosen = report["chosen"]
    return measured_priors(chosen, report.get("effect_params", {}), report.get("effect_params_std", {}))


def _drive(d: Path, name: Path):
    """The demo drive read from the working folder `d`, named by where it will end up (`name`,
    as the user gave it), so that no written file mentions the temporary folder."""
    from ..io import load_drive

    rec, veh = load_drive(d / "recording.csv", d / "vehicle.json")
    warnings = [w.replace(str(d), str(name)) for w in rec.warnings]
    return dataclasses.replace(rec, source=str(name / "recording.csv"), warnings=warnings), veh


def true_values(truth: dict) -> dict[str, float]:
    """The truth by parameter name: θ and the concealed effects' parameters (``sensor_bias.ax``)."""
    out = dict(truth["theta"])
    for e, params in truth["concealed_effect"].items():
        out |= {parameter_name(e, k): float(v) for k, v in params.items()}
    return out


def _before_after(d: Path, truth: dict, runs, report) -> None:
    """report.html, before_after.png and one pair plot per identification, truth marked."""
    values = true_values(truth)
    for k, (label, _, res) in enumerate(runs):
        plot_posterior(
            res.summary, res.samples, d / f"pairplot_{k}.png", truth=values, title=f"posterior, {label}"
        )
    before_after_plot(
        [(label, res) for label, _, res in runs],
        values,
        d / "before_after.png",
        title=f"concealed {', '.join(CONCEALED)}: {' vs '.join(label for label, _, _ in runs)}",
    )
    page = demo_page(
        values, [(label, f, res.summary) for label, f, res in runs], report, d, ", ".join(CONCEALED)
    )
    (d / "report.html").write_text(page)


def _diagnosis(report: dict) -> str:
    """What the diagnosis found, in one line."""
    chosen = ", ".join(report["chosen"]) or "none"
    msg = f"mismatch detected: {report['mismatch_detected']}; effects named: {chosen}"
    return msg + f" (concealed: {', '.join(CONCEALED)}); verdict: {report['verdict']}"


def _readme(b: DemoBudget, runs, diagnosis: str) -> str:
    lines = [
        "vdsbi demo: open report.html",
        f"recording.csv, vehicle.json: a {b.duration:g} s simulated drive; truth.json holds the truth",
    ]
    lines += [
        f"{f}/: identify, {label} (report.html, posterior.json, samples.csv, ...)" for label, f, _ in runs
    ]
    return "\n".join([*lines, f"diagnose/: {diagnosis}", ""])
