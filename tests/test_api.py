"""The Python API's own contracts: typed failures, output directories, θ checks naming the
parameter, simulate's recording, and the observability / design results the CLI prints."""

from __future__ import annotations

import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi import api
from vdsbi.api._validate import PROFILE_V0
from vdsbi.inference import IdentifySettings, StatisticsMLP, identify
from vdsbi.inference._vehicle import seed_prior
from vdsbi.io import InputError, read_recording
from vdsbi.io._errors import SimulationError
from vdsbi.simulator import CHANNELS, PARAM_NAMES, SEED_TRUE_THETA, default_vehicle, seed_profile
from vdsbi.simulator.effects import EffectSettings

GOOD = Path(__file__).parent / "data" / "good"


class _FailingSimulator:
    """Every draw leaves the model's domain."""

    channels = ("ax", "ay")
    inputs = seed_profile(duration=0.5)

    def __call__(self, key, theta):
        n = theta.shape[0]
        return jnp.zeros((n, self.inputs.num_samples, 2)), jnp.zeros(n, bool)


def test_identify_raises_simulation_error_when_every_draw_fails(getkey):
    settings = IdentifySettings(rounds=1, sims_per_round=10, embedding=StatisticsMLP())
    readings = np.zeros((_FailingSimulator.inputs.num_samples, 2))
    with pytest.raises(SimulationError) as info:
        identify(getkey(), _FailingSimulator(), seed_prior(), readings, settings)
    assert info.value.num_usable == 0 and info.value.num_simulated == 10


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"embedding": "lstm"}, "embedding"),
        ({"rounds": 0}, "rounds"),
        ({"sims_per_round": 5}, "sims_per_round"),
    ],
)
def test_settings_are_checked_once_as_input_errors(kwargs, field):
    with pytest.raises(InputError, match=f"settings: {field}: "):
        IdentifySettings(**kwargs)


def test_api_identify_turns_failed_simulations_into_one_line_and_cleans_up(monkeypatch, tmp_path):
    import vdsbi.inference

    def fail(*args, **kwargs):
        raise SimulationError(0, 10)

    monkeypatch.setattr(vdsbi.inference, "identify_problem", fail)
    out = tmp_path / "run"
    with pytest.raises(InputError, match="windows: almost every simulation of this drive failed"):
        options = api.IdentifyOptions(budget=api.Budget(sims=10))
        api.identify(GOOD / "recording.csv", GOOD / "vehicle.json", options, out_dir=out)
    assert not out.exists()


def test_checkpoint_dir_keeps_a_checkpointed_run_and_drops_an_empty_one(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(RuntimeError):
        with api.outputs.checkpoint_dir(out) as d:
            (d / api.outputs.RUN_FILE).write_text("{}")
            raise RuntimeError("killed before the first checkpoint")
    assert not out.exists()
    with pytest.raises(KeyboardInterrupt):
        with api.outputs.checkpoint_dir(out) as d:
            (d / api.outputs.CHECKPOINT).write_bytes(b"round 1")
            raise KeyboardInterrupt
    assert (out / api.outputs.CHECKPOINT).exists()
    with pytest.raises(InputError, match="not empty; use --resume"):
        with api.outputs.checkpoint_dir(out):
            pass
    with api.outputs.checkpoint_dir(out, resume=True) as d:
        assert d == out


@pytest.mark.parametrize(
    "theta, field",
    [({"l_f": 9.0}, "l_f"), ({"C_alpha_r": -1.0}, "C_alpha_r"), ({"mass": 1.0}, "mass")],
)
def test_simulate_names_the_bad_parameter(theta, field):
    with pytest.raises(InputError, match=f"--theta: {field}: "):
        api.simulate(theta, seed_profile(duration=0.5))


def test_simulate_gives_a_recording_with_the_given_inputs(tmp_path):
    src = read_recording(GOOD / "recording.csv")
    res = api.simulate(SEED_TRUE_THETA, src, GOOD / "vehicle.json", v0=None, noise="vehicle", seed=1)
    assert res.ok and res.v0 == pytest.approx(float(src.channels["vx"][0]))
    rec = res.to_recording("sim")
    np.testing.assert_allclose(rec.t, src.t)
    np.testing.assert_array_equal(rec.steer, src.steer)  # float64, as given
    assert rec.channel_names == CHANNELS
    rec.to_csv(tmp_path / "sim.csv")
    assert read_recording(tmp_path / "sim.csv").num_samples == src.num_samples


def test_observability_result_renders_and_saves(tmp_path):
    res = api.observability(default_vehicle(), seed_profile(duration=1.0), label="seed profile, 1 s")
    assert res.report["params"] == list(PARAM_NAMES) and res.report["v0"] == PROFILE_V0
    assert res.markdown().startswith("# Observability: seed profile, 1 s, v0 = 10.5 m/s, seed noise")
    res.save(tmp_path)
    assert json.loads((tmp_path / "fisher.json").read_text())["maneuver"] == "seed profile, 1 s"


def test_simulate_and_observability_take_the_effects_as_one_record():
    # The effects and their values travel together: the drag slows the car in simulate, and
    # its parameter joins the Fisher matrix at the given value in observability.
    drag = EffectSettings(enabled=("aero_drag",), params={"aero_drag": {"CdA": 0.9}})
    inputs = seed_profile(duration=1.0)
    base = api.simulate(SEED_TRUE_THETA, inputs, v0=20.0)
    dragged = api.simulate(SEED_TRUE_THETA, inputs, v0=20.0, effects=drag)
    vx = CHANNELS.index("vx")
    assert base.ok and dragged.ok and dragged.readings[-1, vx] < base.readings[-1, vx]
    res = api.observability(default_vehicle(), inputs, effects=drag)
    assert res.report["params"] == [*PARAM_NAMES, "aero_drag.CdA"] and res.report["effects"] == ["aero_drag"]
    assert res.report["values"]["aero_drag.CdA"] == pytest.approx(0.9)


def test_observability_rejects_a_noise_model_without_channels():
    with pytest.raises(InputError, match="vehicle: noise_std: "):
        api.observability(default_vehicle(), seed_profile(duration=1.0), noise="vehicle")
