"""Adding an effect is one file: a copy of the package with one new module under
`simulator/_effects/` (and nothing else edited) simulates the effect, identifies its parameter,
diagnoses it when a drive hides it, and exports it."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import vdsbi

ROOT = Path(__file__).resolve().parents[1]


def readme_effect() -> str:
    """The effect module the README's "Adding an effect" prints: the whole diff, one new file."""
    text = (ROOT / "README.md").read_text()
    section = text[text.index("### Adding an effect") :]
    return section[section.index("```python\n") + len("```python\n") : section.index("```\n", 10)]


TOY_EFFECT = readme_effect()

SCRIPT = textwrap.dedent(
    """
    import json, sys
    from pathlib import Path

    import jax
    import numpy as np

    import vdsbi
    from vdsbi import api
    from vdsbi.discovery import diagnose_mismatch
    from vdsbi.io import build_recording
    from vdsbi.simulator import CHANNELS, SEED_TRUE_THETA, default_vehicle, random_profile, simulate
    from vdsbi.simulator import theta_from_dict
    from vdsbi.simulator.effects import EFFECTS, EffectSettings

    out = Path(sys.argv[1])
    noise = {"ax": 0.05, "ay": 0.05, "yaw_rate": 0.003, "omega_front": 0.1, "omega_rear": 0.1}
    inputs = random_profile(jax.random.key(5), 8.0)
    ys, ok = simulate(
        theta_from_dict(SEED_TRUE_THETA), inputs, default_vehicle(), v0=15.0,
        effects=EffectSettings(enabled=["tow_pull"], params={"tow_pull": {"force": 800.0}}),
    )
    rng = np.random.default_rng(0)
    cols = {"t": np.asarray(inputs.ts), "steer": np.asarray(inputs.steer),
            "torque_front": np.asarray(inputs.torque_front), "torque_rear": np.asarray(inputs.torque_rear)}
    ys = np.asarray(ys)
    cols |= {c: ys[:, CHANNELS.index(c)] + s * rng.standard_normal(len(ys)) for c, s in noise.items()}
    rec = build_recording(cols, "tow.csv")
    (out / "vehicle.json").write_text(json.dumps({**default_vehicle().to_dict(), "noise_std": noise}))
    options = api.IdentifyOptions(
        model=api.ModelOptions(add_effects=("tow_pull",)),
        budget=api.Budget(rounds=1, sims=100, epochs=3, num_samples=200, ppc_draws=10),
    )
    res = api.identify(rec, out / "vehicle.json", options, out_dir=out / "run")
    found = diagnose_mismatch(
        rec, out / "vehicle.json", candidates=("tow_pull", "sensor_bias"), max_effects=1,
        num_draws=50, single_iters=6, final_iters=10, final_dt=0.005, plots=False,
    )
    exported = json.loads(api.export(out / "run", "json"))
    print(json.dumps({
        "package": vdsbi.__file__,
        "registered": "tow_pull" in EFFECTS,
        "simulated": bool(ok),
        "estimate": res.estimate["tow_pull.force"],
        "interval": res.interval["tow_pull.force"],
        "chosen": found.report["chosen"],
        "exported": "tow_pull.force" in json.dumps(exported),
    }))
    """
)


def test_one_new_module_is_simulated_identified_diagnosed_and_exported(tmp_path):
    package = tmp_path / "src" / "vdsbi"
    shutil.copytree(Path(vdsbi.__file__).parent, package, ignore=shutil.ignore_patterns("__pycache__"))
    (package / "simulator" / "_effects" / "_tow_pull.py").write_text(TOY_EFFECT)
    run = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(tmp_path)],
        # the suite's compiler flags (conftest): the copy compiles as cheaply as the tests do
        env={
            "PYTHONPATH": str(tmp_path / "src"),
            "PATH": "/usr/bin:/bin",
            "JAX_PLATFORMS": "cpu",
            "XLA_FLAGS": os.environ["XLA_FLAGS"],
        },
        cwd=tmp_path,  # `-c` puts the working directory first on the path
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got["package"].startswith(str(tmp_path))  # the copy, not the installed package
    assert got["registered"] and got["simulated"] and got["exported"]
    lo, hi = got["interval"]
    assert lo <= 800.0 <= hi and abs(got["estimate"] - 800.0) < 150.0
    assert got["chosen"] == ["tow_pull"]
