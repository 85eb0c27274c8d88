"""`vdsbi simulate`: writes a contract recording that `read_recording` reads back; bad values
give one-line errors naming the field (exit 2) and no output."""

import json
from pathlib import Path

import numpy as np
import pytest

from vdsbi.cli import main
from vdsbi.io import read_recording, read_vehicle
from vdsbi.problem import smoothed_yaw_rate
from vdsbi.simulator import CHANNELS, PARAM_NAMES, SEED_TRUE_THETA, seed_profile, simulate
from vdsbi.simulator.effects import EffectSettings
from vdsbi.simulator.models import steady_lateral_state

GOOD = Path(__file__).parent / "data" / "good"
VEHICLE = str(GOOD / "vehicle.json")


def test_profile_round_trip_and_plot(tmp_path, capsys):
    out, png = tmp_path / "sim.csv", tmp_path / "sim.png"
    assert (
        main(["simulate", "--vehicle", VEHICLE, "--profile", "seed", "--out", str(out), "--plot", str(png)])
        == 0
    )
    assert "wrote" in capsys.readouterr().out
    rec = read_recording(out)
    assert rec.channel_names == CHANNELS
    inputs = seed_profile()
    np.testing.assert_allclose(rec.t, np.arange(inputs.num_samples) * inputs.dt, atol=1e-12)
    np.testing.assert_allclose(rec.steer, np.asarray(inputs.steer), atol=1e-7)
    np.testing.assert_allclose(rec.torque_front, np.asarray(inputs.torque_front))
    theta = np.array([SEED_TRUE_THETA[n] for n in PARAM_NAMES])
    ys, ok = simulate(theta, inputs, read_vehicle(VEHICLE), v0=10.5)
    assert ok
    np.testing.assert_allclose(rec.measured(CHANNELS), ys, rtol=1e-6, atol=1e-7)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_recording_inputs_theta_file_effects_and_noise(tmp_path):
    src = read_recording(GOOD / "recording.csv")
    theta_file = tmp_path / "theta.json"
    theta_file.write_text(json.dumps({"l_f": 1.2, "C_alpha_r": 7e4}))
    out = tmp_path / "sim.csv"
    argv = ["simulate", "--vehicle", VEHICLE, "--inputs", str(GOOD / "recording.csv")]
    argv += ["--theta", str(theta_file), "--effects", '{"aero_drag": {"CdA": 0.6}}']
    argv += ["--noise", "vehicle", "--seed", "3", "--out", str(out)]
    assert main(argv) == 0
    rec = read_recording(out)
    np.testing.assert_allclose(rec.t, src.t)
    np.testing.assert_allclose(rec.torque_front, src.torque_front)
    # v0 from the recording's vx; the noise is the vehicle's additive noise on ax, ay, yaw_rate
    vehicle = read_vehicle(VEHICLE)
    theta = np.array([1.2, 0.5, 1e5, 1e5, 6e4, 7e4])
    # The recording is predicted from its own initial state: its first speed, its smoothed yaw
    # rate and the steady-state side speed for it (as a problem's windows start).
    v0 = float(src.channels["vx"][0])
    r0 = float(smoothed_yaw_rate(src)[0])
    lateral0 = np.array([float(x) for x in steady_lateral_state(theta, vehicle, v0, r0)])
    clean, ok = simulate(
        theta,
        src.inputs(),
        vehicle,
        v0=v0,
        effects=EffectSettings(enabled=["aero_drag"], params={"aero_drag": {"CdA": 0.6}}),
        lateral0=lateral0,
    )
    resid = rec.measured(CHANNELS) - clean
    for i, c in enumerate(CHANNELS):
        std = vehicle.noise_std.get(c, 0.0)
        if std:
            assert 0.8 * std < resid[:, i].std() < 1.2 * std, c
        else:
            assert np.abs(resid[:, i]).max() < 1e-5 * np.abs(clean[:, i]).max() + 1e-7, c


@pytest.mark.parametrize(
    "extra,field",
    [
        (["--theta", '{"l_f": 5.0}'], "l_f"),
        (["--theta", '{"C_kappa_f": -1}'], "C_kappa_f"),
        (["--theta", '{"mass": 1200}'], "mass"),
        (["--theta", '{"h_cog": "high"}'], "h_cog"),
        (["--theta", "no_such_file.json"], "--theta"),
        (["--theta", "{l_f: 1}"], "--theta"),
        (["--effects", '{"warp_drive": {}}'], "warp_drive"),
        (["--effects", '{"aero_drag": {"cda": 0.5}}'], "aero_drag.cda"),
        (["--effects", '{"road_grade": {"grade": null}}'], "road_grade.grade"),
        (["--v0", "-2"], "v0"),
        (["--v0", "nan"], "v0"),
        (
            [
                "--noise",
                "vehicle",
                "--vehicle",
                str(Path(__file__).parent / "data" / "bad" / "vehicle_missing_mass.json"),
            ],
            "mass",
        ),
    ],
)
def test_bad_values_exit_2_naming_the_field(tmp_path, capsys, extra, field):
    out = tmp_path / "sim.csv"
    argv = ["simulate", "--vehicle", VEHICLE, "--profile", "seed", "--out", str(out), *extra]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("vdsbi: error:") and field in err and "\n" not in err
    assert not out.exists()


def test_noise_vehicle_without_noise_std_and_bad_out(tmp_path, capsys):
    bare = tmp_path / "vehicle.json"
    data = read_vehicle(VEHICLE).to_dict()
    data.pop("noise_std")
    bare.write_text(json.dumps(data))
    argv = ["simulate", "--vehicle", str(bare), "--profile", "seed", "--noise", "vehicle"]
    assert main([*argv, "--out", str(tmp_path / "a.csv")]) == 2
    assert "noise_std" in capsys.readouterr().err
    assert (
        main(["simulate", "--vehicle", VEHICLE, "--profile", "seed", "--out", str(tmp_path / "a.txt")]) == 2
    )
    assert "--out" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == [bare]
