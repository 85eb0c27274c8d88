"""Terms outside the library: a term the generator adds is found by sparse selection through the
simulator, with its coefficient; a clean recording yields no term; the formula reads right."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi.discovery._candidates import effect_space
from vdsbi.discovery._fit import Fitter
from vdsbi.discovery._terms import discover_terms, select_terms
from vdsbi.io import build_recording
from vdsbi.problem import make_problem
from vdsbi.simulator import CHANNELS, PARAM_NAMES, SEED_TRUE_THETA, default_vehicle, random_profile, solve
from vdsbi.simulator.effects import term_effect, term_formula
from vdsbi.simulator.models import VehicleModel
from vdsbi.simulator.solvers import Solver

NOISE = {"ax": 0.08, "ay": 0.08, "yaw_rate": 0.003, "omega_front": 0.08, "omega_rear": 0.08}
CANDIDATES = (
    "side_quadratic",
    "side_linear",
    "ay_scale",
    "yaw_rate_scale",
    "drag_constant",
    "yaw_moment_linear",
    "yaw_moment_load_transfer",
    "yaw_damping",
)
TRUE_C = -0.05  # lateral force += −0.05·m·a_c·|a_c|: 1.25 m/s² less at a_c = 5 m/s²
# (term, c, words of its formula): a missing force, and a missing yaw moment that couples
# braking and cornering (what load-sensitive tyres under load transfer give)
ADDED = [
    ("side_quadratic", TRUE_C, ("lateral force", "a_c·|a_c|")),
    ("yaw_moment_load_transfer", -0.08, ("yaw moment", "ax·a_c")),
]


def _recording(seed: int, c: float, key: str = "side_quadratic"):
    vehicle = dataclasses.replace(default_vehicle(), noise_std=NOISE)
    theta = jnp.array([SEED_TRUE_THETA[n] for n in PARAM_NAMES])
    inputs = random_profile(jax.random.key(seed), 12.0)
    model = VehicleModel(vehicle=vehicle, effects=(term_effect((key,))(),))
    ys, ok = solve(model, theta, inputs, jnp.asarray(18.0), (jnp.array([c]),), Solver(dt=0.005))
    assert ok
    rng = np.random.default_rng(seed)
    ys = np.asarray(ys) + rng.standard_normal(ys.shape) * np.array([NOISE.get(ch, 0.0) for ch in CHANNELS])
    cols = {"t": np.asarray(inputs.ts), "steer": np.asarray(inputs.steer)}
    cols.update(torque_front=np.asarray(inputs.torque_front), torque_rear=np.asarray(inputs.torque_rear))
    cols.update({ch: ys[:, CHANNELS.index(ch)] for ch in NOISE})
    return build_recording(cols, f"term {c}"), vehicle


def _discover(seed, c, key="side_quadratic"):
    rec, vehicle = _recording(seed, c, key)
    fitter = Fitter(make_problem(rec, vehicle), dt=0.005, effects=effect_space(()))
    z0 = fitter.initial_z(np.array([SEED_TRUE_THETA[n] for n in PARAM_NAMES]))
    base = fitter.fit((), z0, max_iter=20)
    return discover_terms(base, fitter, (), max_terms=2, candidates=CANDIDATES), base


@pytest.mark.parametrize("key,c,words", ADDED, ids=[a[0] for a in ADDED])
def test_added_term_is_recovered_with_its_coefficient(x64, key, c, words):
    found, base = _discover(1, c, key)
    assert [t["key"] for t in found.terms][:1] == [key], found.screened
    t = found.terms[0]
    assert t["coefficient"] == pytest.approx(c, rel=0.15)
    assert abs(t["coefficient"] - c) < 4 * t["std"] + 0.02 * abs(c)
    assert found.fit.chi2 < base.chi2 and found.gain >= 3.0
    assert all(w in t["formula"] for w in words), t["formula"]


def test_clean_recording_yields_no_term(x64):
    found, _ = _discover(2, 0.0)
    assert found.terms == [] and found.fit is None
    assert max(found.screened.values()) < 3.0


def test_selection_picks_the_column_that_made_the_residual():
    rng = np.random.default_rng(0)
    base = rng.standard_normal((400, 3))
    terms = rng.standard_normal((400, 5))
    r = -2.0 * terms[:, 3] + rng.standard_normal(400)  # residual = data − model: term 3 missing
    picked, screened = select_terms(r, base, terms, tuple("abcde"), max_terms=3)
    assert [k for k, _ in picked] == ["d"] and screened["d"] > 100


def test_formula_reads_as_an_equation():
    assert term_formula("ay_scale", 0.05) == "ay measured as ay + 0.05·ay (c in -)"
    assert term_formula("side_constant", -0.2).startswith("lateral force += -0.2·m ")


def _section(
    p_before, p_after, held_after, held_terms, effects=("torque_gain",), terms=None, p_terms=None, tau=None
):
    from types import SimpleNamespace as NS

    from vdsbi.discovery._terms import HeldOutScores, terms_section

    td = None
    if terms is not None:
        fit = NS() if terms else None
        td = NS(terms=terms, fit=fit, dropped=[], screened={}, gain=10.0 if terms else None)
    return terms_section(
        p_before=p_before,
        p_after=p_after,
        chosen=effects,
        terms=td,
        p_terms=p_terms,
        held=HeldOutScores(held_after, held_terms, 100, tau),
        alpha=0.05,
    )


def test_explanation_says_what_explained_the_mismatch():
    held = {"ay": {"chi2_dof": 1.3}, "yaw_rate": {"chi2_dof": 1.2}}
    better = {"ay": {"chi2_dof": 1.0}, "yaw_rate": {"chi2_dof": 1.0}}
    same = {"ay": {"chi2_dof": 1.299}, "yaw_rate": {"chi2_dof": 1.2}}
    term = [{"formula": "ay measured as ay + 0.05·ay (c in -)"}]
    assert _section(0.3, 0.3, held, None, ())["explanation"] == "none"
    assert _section(0.001, 0.2, better, None)["explanation"] == "library"
    # the residual test passes but the held-out χ²/dof stays above 1.1: not claimed
    assert _section(0.001, 0.2, held, None)["explanation"] == "unexplained"
    out = _section(0.001, 0.001, held, better, terms=term, p_terms=0.3)
    assert out["explanation"] == "discovered term"
    assert out["held_out_gain"] == pytest.approx(50.0 * (np.log(1.3) + np.log(1.2)))
    # the same gain on a residual correlated over 40 samples: 40 times fewer independent samples
    out = _section(0.001, 0.001, held, better, terms=term, p_terms=0.3, tau={"ay": 40.0, "yaw_rate": 40.0})
    assert out["explanation"] == "unexplained" and out["held_out_gain"] < 3.0
    assert "ay + 0.05·ay" in out["sentence"]
    # a term that does not predict the held-out part better is not claimed
    out = _section(0.001, 0.001, held, same, terms=term, p_terms=0.3)
    assert out["explanation"] == "unexplained" and "does not predict" in out["sentence"]
    out = _section(0.001, 0.001, held, None, (), terms=[])
    assert out["explanation"] == "unexplained" and "left unexplained" in out["sentence"]
