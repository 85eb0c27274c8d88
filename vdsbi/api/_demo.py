"""`demo`: simulate a drive with a concealed effect, identify θ with the base model, diagnose
the mismatch, and leave everything in one folder."""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Callable
from pathlib import Path

from ._diagnose import diagnose
from ._identify import IdentifyResult, identify
from ._outputs import output_dir

#: The effect hidden in the demo recording (identify's model does not know it).
CONCEALED = {"sensor_bias": {"ax": 0.3, "ay": -0.25, "yaw_rate": 0.0}}
NOISE_STD = {"ax": 0.05, "ay": 0.05, "yaw_rate": 0.003, "omega_front": 0.1, "omega_rear": 0.1, "vx": 0.03}
#: Initial speed of the demo drive, m/s.
DEMO_V0 = 15.0


@dataclasses.dataclass
class DemoResult:
    """Where the demo wrote its files, what `identify` found, the diagnosis in one line, and
    the wall time in seconds."""

    out: Path
    identified: IdentifyResult
    diagnosis: str
    seconds: float


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
            effects=list(CONCEALED),
            effect_params=CONCEALED,
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
) -> DemoResult:
    """Simulate, identify and diagnose a drive with a concealed sensor bias, into `out`
    (default: vdsbi-demo-<time>): recording.csv, vehicle.json, truth.json, identify/,
    diagnose/ and README.txt.

    Args:
        quick: a 10 s drive, 2 x 300 simulations, no diagnosis plots (default 20 s, 2 x 1000).
        seed: the drive's and the methods' seed.
        run_diagnosis: run the mismatch diagnosis after identify.
        progress: tqdm bars while identifying.
        log: where progress lines go (default: nowhere).
    """
    t_start = time.perf_counter()
    name = Path(out or time.strftime("vdsbi-demo-%Y%m%d-%H%M%S"))
    say = log or (lambda s: None)
    duration, rounds, sims = (10.0, 2, 300) if quick else (20.0, 2, 1000)
    with output_dir(name) as d:
        say(f"1/3 simulating a {duration:g} s drive of the built-in vehicle with a concealed effect")
        truth = demo_recording(d, duration=duration, seed=seed)
        rec, veh = _drive(d, name)
        say(f"2/3 identify: {rounds} rounds x {sims} simulations (stats embedding)")
        res = identify(
            rec,
            veh,
            rounds=rounds,
            sims=sims,
            embedding="stats",
            seed=seed,
            out_dir=d / "identify",
            progress=progress,
            log=say,
        )
        lines = [res.table(), "", "true values:"]
        lines += [f"  {k:<10} {v:.4g}" for k, v in truth["theta"].items()]
        (d / "identify" / "table.txt").write_text("\n".join(lines) + "\n")
        say(res.table())
        diagnosis = "skipped (--no-diagnose)"
        if run_diagnosis:
            say("3/3 diagnose: looking for missing physics")
            diagnosis = _diagnosis(d, rec, veh, seed=seed, quiet=log is None, plots=not quick)
        (d / "README.txt").write_text(
            "vdsbi demo\n"
            f"recording.csv, vehicle.json: a {duration:g} s simulated drive; truth.json holds the truth\n"
            "identify/: posterior.json, samples.csv, pairplot.png, ppc.png, estimator.npz, table.txt\n"
            f"diagnose/: {diagnosis}\n"
        )
    return DemoResult(name.resolve(), res, diagnosis, time.perf_counter() - t_start)


def _drive(d: Path, name: Path):
    """The demo drive read from the working folder `d`, named by where it will end up (`name`,
    as the user gave it), so that no written file mentions the temporary folder."""
    from ..io import load_drive

    rec, veh = load_drive(d / "recording.csv", d / "vehicle.json")
    return dataclasses.replace(rec, source=str(name / "recording.csv")), veh


def _diagnosis(d: Path, rec, veh, *, seed: int, quiet: bool, plots: bool) -> str:
    """Run the diagnosis on the demo drive into d/diagnose; what it found, in one line."""
    dres = diagnose(rec, veh, d / "diagnose", seed=seed, quiet=quiet, plots=plots)
    chosen = ", ".join(dres.chosen) or "none"
    msg = f"mismatch detected: {dres.mismatch_detected}; effects named: {chosen}"
    msg += f" (concealed: {', '.join(CONCEALED)}); verdict: {dres.report['verdict']}"
    if dres.mismatch_detected:
        # the identify step above used the base model on this very drive
        msg += (
            "\n  so the identify result above came from a misspecified model: re-identify "
            "with the named effect (report.md has θ refitted with it)"
        )
    return msg
