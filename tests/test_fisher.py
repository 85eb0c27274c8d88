"""Fisher information by autodiff: analytic toy, finite differences, the seed's MC estimator, CLI."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi.diagnostics import fisher_report, model_fisher, score_fisher_mc
from vdsbi.diagnostics._fisher import fisher_from_jacobian, fisher_information, noise_std, scaled_mean_fn
from vdsbi.estimation import GaussianPrior, StepControl, laplace_covariance, levenberg_marquardt
from vdsbi.simulator import (
    CHANNELS,
    PARAM_NAMES,
    SEED_CHANNELS,
    SEED_TRUE_THETA,
    SeedManeuver,
    default_vehicle,
    make_model,
    seed_profile,
)
from vdsbi.simulator.solvers import Solver

THETA = np.array([SEED_TRUE_THETA[n] for n in PARAM_NAMES])


def test_linear_gaussian_fisher_is_analytic(x64, getkey):
    # y_t = A_t θ + ε_t, ε_t ~ N(0, diag(σ_t²)): F = Σ_t A_tᵀ diag(σ_t⁻²) A_t exactly.
    T, C, P = 7, 3, 4
    a = jax.random.normal(getkey(), (T, C, P))
    std = jnp.exp(jax.random.normal(getkey(), (T, C)))
    theta = jax.random.normal(getkey(), (P,))
    f = fisher_information(lambda th: jnp.einsum("tcp,p->tc", a, th), theta, std)
    expected = sum(a[t].T @ np.diag(1 / np.asarray(std[t]) ** 2) @ a[t] for t in range(T))
    np.testing.assert_allclose(f, expected, rtol=1e-12)
    # Nonlinear toy with a known answer: y_t = exp(−b t) a, one channel, σ = s.
    ts = jnp.linspace(0, 2, 11)
    a0, b0, s = 2.0, 0.7, 0.3
    f = fisher_information(
        lambda p: (p[0] * jnp.exp(-p[1] * ts))[:, None], jnp.array([a0, b0]), jnp.full((11, 1), s)
    )
    da, db = jnp.exp(-b0 * ts), -a0 * ts * jnp.exp(-b0 * ts)
    expected = np.array([[da @ da, da @ db], [db @ da, db @ db]]) / s**2
    np.testing.assert_allclose(f, expected, rtol=1e-12)


def test_noise_floor_bounds_information_at_zero_crossings(x64):
    ys = jnp.array([[0.0, 10.0], [1.0, 10.0], [-1.0, 10.0]])
    std = noise_std(ys, jnp.array([0.1, 0.05]), jnp.zeros(2), floor_fraction=0.1)
    rms = np.sqrt(2 / 3)
    np.testing.assert_allclose(std[:, 0], [0.1 * 0.1 * rms, 0.1, 0.1])
    np.testing.assert_allclose(std[:, 1], 0.5)
    assert np.all(np.isfinite(fisher_from_jacobian(jnp.ones((3, 2, 1)), std)))


@pytest.fixture(scope="module")
def short_case():
    """Float64 Fisher of the 6 θ on the first 1 s of the seed maneuver (braking part shifted in)."""
    with jax.enable_x64(True):
        inputs = seed_profile(duration=1.0, maneuver=SeedManeuver(torque_period=1.0))
        model = make_model(default_vehicle())
        fisher = model_fisher(model, jnp.asarray(THETA), inputs, 10.5)
        yield model, inputs, fisher


def test_autodiff_fisher_matches_finite_differences(x64, short_case):
    model, inputs, fisher = short_case
    idx = jnp.asarray([CHANNELS.index(c) for c in SEED_CHANNELS])
    mean = jax.jit(scaled_mean_fn(model, fisher.scale, inputs, jnp.asarray(10.5), idx, Solver()))
    z = fisher.values / fisher.scale
    h = 1e-5  # relative step in scaled units; central differences: O(h²) ≈ 1e-10 truncation
    cols = [(mean(z + h * e) - mean(z - h * e)) / (2 * h) for e in jnp.eye(6)]
    jac_fd = jnp.stack(cols, axis=-1)
    f_fd = fisher_from_jacobian(jac_fd, fisher.std)
    err = np.abs(np.asarray(f_fd - fisher.fim_scaled)) / np.abs(np.diag(fisher.fim_scaled)).max()
    assert err.max() < 1e-4, err.max()
    # Elementwise too, on the diagonal (each parameter's own information).
    np.testing.assert_allclose(np.diag(f_fd), np.diag(fisher.fim_scaled), rtol=1e-4)
    # ...and the physical-unit F is the scaled one unscaled.
    np.testing.assert_allclose(
        fisher.fim * np.outer(fisher.scale, fisher.scale), fisher.fim_scaled, rtol=1e-12
    )


def test_mc_score_estimate_converges_to_autodiff_fisher(x64, short_case, getkey):
    _, _, fisher = short_case
    jac = fisher.jac
    ref = np.asarray(fisher.fim_scaled)
    errs = {}
    for n in (64, 1024, 16384):
        est = np.mean([np.asarray(score_fisher_mc(getkey(), jac, fisher.std, n)) for _ in range(3)], 0)
        # Compare in the whitened frame so every direction counts: ‖F⁻½ F̂ F⁻½ − I‖.
        w, v = np.linalg.eigh(ref)
        isq = v @ np.diag(w**-0.5) @ v.T
        errs[n] = np.linalg.norm(isq @ est @ isq - np.eye(6))
    # Error ∝ 1/√n: 16× more samples → ≈ 4× smaller; demand at least 2.5× per step.
    assert errs[1024] < errs[64] / 2.5, errs
    assert errs[16384] < errs[1024] / 2.5, errs
    assert errs[16384] < 0.1, errs


def test_report_rank_weakest_direction_and_crb(x64, short_case):
    _, _, fisher = short_case
    rep = fisher_report(fisher)
    assert rep["params"] == list(PARAM_NAMES)
    assert rep["rank"]["value"] == 6 and rep["rank"]["nonsingular"]
    ev = np.asarray(rep["eigenvalues"])
    assert np.all(np.diff(ev) >= 0) and rep["condition_number"] == pytest.approx(ev[-1] / ev[0])
    # CRB std = sqrt(diag F⁻¹) in physical units.
    crb = np.sqrt(np.diag(np.linalg.inv(np.asarray(fisher.fim))))
    np.testing.assert_allclose([rep["crb_std"][n] for n in PARAM_NAMES], crb, rtol=1e-6)
    corr = np.asarray(rep["correlation"])
    np.testing.assert_allclose(np.diag(corr), 1.0, rtol=1e-9)
    assert np.all(np.abs(corr) <= 1 + 1e-9)
    weak = np.array([rep["weakest_direction"][n] for n in PARAM_NAMES])
    assert np.linalg.norm(weak) == pytest.approx(1.0)
    # The weakest direction's information is the smallest eigenvalue.
    fz = np.asarray(fisher.fim_scaled)
    assert weak @ fz @ weak == pytest.approx(ev[0], rel=1e-6)


def test_rank_decision_detects_a_null_direction(x64):
    # Two parameters entering only through their sum: rank 1, infinite bounds.
    from vdsbi.diagnostics._fisher import Fisher

    jac = jnp.ones((10, 1, 2))
    f = fisher_from_jacobian(jac, jnp.ones((10, 1)))
    fisher = Fisher(
        names=("a", "b"),
        channels=("y",),
        values=jnp.ones(2),
        scale=jnp.ones(2),
        fim_scaled=f,
        readings=jnp.zeros((10, 1)),
        std=jnp.ones((10, 1)),
        jac=jac,
    )
    rep = fisher_report(fisher)
    assert rep["rank"]["value"] == 1 and not rep["rank"]["nonsingular"]
    assert np.isinf(rep["crb_std"]["a"]) and np.isinf(rep["crb_std"]["b"])
    w = rep["weakest_direction"]
    assert abs(abs(w["a"]) - abs(w["b"])) < 1e-9 and w["a"] * w["b"] < 0


def test_levenberg_marquardt_with_prior_is_ridge_and_compiles_once(x64, getkey):
    # Linear residual + Gaussian prior: the minimiser is the ridge solution and the Laplace
    # covariance is (AᵀA + diag(prec))⁻¹ exactly; the iteration cap is traced, not static.
    a = jax.random.normal(getkey(), (40, 3))
    y = jax.random.normal(getkey(), (40,))
    prec, mean = jnp.array([0.5, 2.0, 1.0]), jnp.array([1.0, -1.0, 0.0])
    traces = []

    @jax.jit
    def fit(z0, max_steps):
        traces.append(None)
        return levenberg_marquardt(
            lambda z: a @ z - y,
            z0,
            prior=GaussianPrior(prec, mean),
            max_steps=max_steps,
            control=StepControl(damping=1e-9),
        )

    short, sol = fit(jnp.zeros(3), 1), fit(jnp.zeros(3), 10)
    assert len(traces) == 1 and int(short.num_steps) == 1 and bool(sol.converged)
    h = a.T @ a + jnp.diag(prec)
    np.testing.assert_allclose(sol.z, np.linalg.solve(h, a.T @ y + prec * mean), rtol=1e-9)
    np.testing.assert_allclose(laplace_covariance(sol.jacobian, prec), np.linalg.inv(h), rtol=1e-9)
    assert float(sol.cost) == pytest.approx(
        0.5 * float(jnp.sum((a @ sol.z - y) ** 2)) + 0.5 * float(jnp.sum(prec * (sol.z - mean) ** 2))
    )


def test_cli_observability_writes_fisher_json(tmp_path):
    from vdsbi.cli import main

    veh = tmp_path / "vehicle.json"
    veh.write_text(json.dumps(default_vehicle().to_dict()))
    out = tmp_path / "obs"
    rc = main(
        ["observability", "--vehicle", str(veh), "--profile", "seed", "--duration", "1.0", "--out", str(out)]
    )
    assert rc == 0
    rep = json.loads((out / "fisher.json").read_text())
    for key in ("params", "fim", "eigenvalues", "condition_number", "crb_std", "weakest_direction"):
        assert key in rep
    assert rep["params"] == list(PARAM_NAMES)
    assert np.asarray(rep["fim"]).shape == (6, 6)
    assert set(rep["crb_std"]) == set(PARAM_NAMES) and all(v > 0 for v in rep["crb_std"].values())
    assert "correlation" in rep and "rank" in rep and "tolerance" in rep["rank"]
    assert (out / "fisher.md").read_text().startswith("#")
    # --noise vehicle without noise_std for the channels is a user error (exit 2), no output.
    rc = main(
        [
            "observability",
            "--vehicle",
            str(veh),
            "--profile",
            "seed",
            "--noise",
            "vehicle",
            "--out",
            str(tmp_path / "x"),
        ]
    )
    assert rc == 2 and not (tmp_path / "x").exists()
