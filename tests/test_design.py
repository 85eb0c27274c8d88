"""Excitation design: the objective increases, hard limits hold by construction, response limits
are enforced, and the CLI writes a valid recording with before/after bounds."""

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi.diagnostics import Limits, Maneuver, check_limits, design_maneuver, design_problem
from vdsbi.simulator import PARAM_NAMES, SEED_TRUE_THETA, default_vehicle, make_model

THETA = jnp.asarray([SEED_TRUE_THETA[n] for n in PARAM_NAMES])
LIMITS = Limits(duration=1.0)


def test_maneuver_respects_hard_limits_for_any_parameters(getkey):
    # Whatever the unconstrained parameters, steer and torques stay inside their limits.
    lim = Limits(duration=2.0, max_steer=0.07, max_drive=500.0, max_brake=1000.0, brake_front_share=0.6)
    base = Maneuver.seed_like(lim)
    for _ in range(5):
        leaves, tree = jax.tree.flatten(base)
        leaves = [10 * jax.random.normal(getkey(), jnp.shape(x)) for x in leaves]
        man = jax.tree.unflatten(tree, leaves)
        u = man.inputs(lim)
        assert np.abs(np.asarray(u.steer)).max() <= 0.07 + 1e-12
        tf, tr = np.asarray(u.torque_front), np.asarray(u.torque_rear)
        assert tf.max() <= 500.0 + 1e-9 and tr.max() <= 1e-9
        assert (-np.minimum(tf, 0) - np.minimum(tr, 0)).max() <= 1000.0 + 1e-6
        # Brake balance is the vehicle's: rear brake = (1 − share)/share × front brake.
        braking = tf < -1e-6
        np.testing.assert_allclose(tr[braking], tf[braking] * 0.4 / 0.6, rtol=1e-5)
        assert lim.v0_min <= float(man.initial_speed(lim)) <= lim.v0_max
    # The seed-like start reproduces the seed's levels and speed (default limits).
    seed_like = Maneuver.seed_like(LIMITS)
    u = seed_like.inputs(LIMITS)
    assert float(seed_like.initial_speed(LIMITS)) == pytest.approx(10.5)
    assert np.asarray(u.torque_front)[0] == pytest.approx(600.0, rel=1e-3)
    assert np.asarray(u.torque_front)[-1] == pytest.approx(-0.65 * 1200.0, rel=1e-3)


def test_design_increases_information_within_limits(x64):
    model = make_model(default_vehicle())
    problem = design_problem(model, THETA, LIMITS, target="C_kappa_r")
    start = Maneuver.seed_like(LIMITS)
    res = design_maneuver(problem, start, num_steps=3, learning_rate=0.1)
    info = res.history["information"]
    assert res.best_step > 0
    assert info[res.best_step] > info[0] + 0.05  # −log CRB variance of C_kappa_r rose
    assert all(res.history["feasible"][[0, res.best_step]])
    chk = check_limits(
        model, THETA, res.maneuver.inputs(LIMITS), float(res.maneuver.initial_speed(LIMITS)), LIMITS
    )
    assert chk["respected"], chk
    # The design objective is what it claims: −log of the C_kappa_r entry of F⁻¹ (scaled).
    # (Compiled, as the optimiser runs it: op by op, each call costs seconds.)
    obj = eqx.filter_jit(problem)(res.maneuver)
    fisher = eqx.filter_jit(lambda m: problem.fisher_scaled(m.inputs(LIMITS), m.initial_speed(LIMITS))[0])
    fz = fisher(res.maneuver)
    assert float(obj.information) == pytest.approx(-np.log(np.linalg.inv(np.asarray(fz))[3, 3]), rel=1e-9)


def test_check_limits_flags_a_violation(x64):
    model = make_model(default_vehicle())
    start = Maneuver.seed_like(LIMITS)
    tight = Limits(duration=1.0, ay_fraction=0.01)
    chk = check_limits(model, THETA, start.inputs(LIMITS), 10.5, tight)
    assert chk["max_abs_ay"] > chk["ay_limit"] and not chk["respected"]
    slow = Limits(duration=1.0, v_min=1.0, v0_min=1.0, v0_max=5.0, v_max=5.0)
    assert not check_limits(model, THETA, start.inputs(LIMITS), 10.5, slow)["respected"]


def test_cli_design_writes_recording_and_bounds(tmp_path):
    from vdsbi.cli import main
    from vdsbi.io import read_recording

    veh = tmp_path / "vehicle.json"
    veh.write_text(json.dumps(default_vehicle().to_dict()))
    out = tmp_path / "design"
    rc = main(
        [
            "design",
            "--vehicle",
            str(veh),
            "--steps",
            "2",
            "--learning-rate",
            "0.1",
            "--duration",
            "1.0",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    rec = read_recording(out / "maneuver.csv")
    assert rec.num_samples == 201 and set(rec.channel_names) >= {
        "ax",
        "ay",
        "yaw_rate",
        "omega_front",
        "omega_rear",
    }
    b = json.loads((out / "bounds.json").read_text())
    assert b["limits_check"]["respected"]
    assert set(b["before"]["crb_std"]) == set(PARAM_NAMES) == set(b["after"]["crb_std"])
    assert b["target"] == "C_kappa_r"
    assert (out / "bounds.md").exists() and (out / "design.json").exists()
