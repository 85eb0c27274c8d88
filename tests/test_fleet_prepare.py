"""A platform's preparation: an estimator that did not train is no estimator."""

import jax
import numpy as np

from vdsbi.fleet._manifest import read_manifest


def test_a_platform_whose_estimator_diverged_sends_its_drives_to_identify(tmp_path, monkeypatch):
    """A diverged estimator (validation loss not finite) is no estimator: the platform says why,
    and nothing is saved for later runs to reuse."""
    from types import SimpleNamespace

    from vdsbi.fleet import AmortizedSettings, _prepare, simulated_fleet

    manifest = simulated_fleet(tmp_path / "fleet", cars=1, drives=1, duration=20.0, changes=(), seed=2)
    drives = read_manifest(manifest)
    diverged = SimpleNamespace(info={"best_val_loss": float("inf")})
    monkeypatch.setattr(_prepare, "train_estimator", lambda *a, **k: diverged)
    out = tmp_path / "out"
    platform, folder, why = _prepare.prepare_platform(
        drives[0].vehicle, drives, out=out, settings=AmortizedSettings(simulations=100), seed=0
    )
    assert platform is not None and folder is None and "did not train" in why
    assert not list(out.glob("platforms/*/estimator.json"))


def test_a_simulated_window_with_a_non_finite_statistic_is_left_out_of_training(tmp_path, monkeypatch):
    """One non-finite row would make the estimator's standardisation NaN: it is dropped, counted,
    and the estimator trains to a finite loss."""
    import jax.numpy as jnp

    from vdsbi.fleet import AmortizedSettings, _amortized, simulated_fleet
    from vdsbi.fleet._platform import WINDOW_SECONDS, drive_problem, make_platform
    from vdsbi.fleet._shape import fixed_shape
    from vdsbi.fleet._windows import window_pool
    from vdsbi.inference import TrainingSettings

    manifest = simulated_fleet(tmp_path / "fleet", cars=1, drives=1, duration=20.0, changes=(), seed=2)
    (drive,) = read_manifest(manifest)
    problem = drive_problem(drive.recording, drive.vehicle)
    platform = make_platform(drive.vehicle, [problem])
    pool = window_pool([fixed_shape(problem, WINDOW_SECONDS)], platform.effects)
    real = _amortized.simulate_batch

    def one_overflow(*args):
        x, ok = real(*args)
        return x.at[0].set(jnp.inf), ok

    monkeypatch.setattr(_amortized, "simulate_batch", one_overflow)
    training = TrainingSettings(batch_size=64, max_epochs=3, patience=2)
    settings = AmortizedSettings(simulations=200, training=training)
    est = _amortized.train_estimator(jax.random.key(0), pool, platform, settings)
    assert est.info["windows_dropped"] >= 1
    assert np.isfinite(est.info["best_val_loss"])


def test_the_window_statistics_solve_matches_lapack_without_calling_it():
    """The small solve in the window statistics is written out (no batched LAPACK kernel,
    which can hang a single-threaded worker) and agrees with LAPACK to float32 rounding."""
    from vdsbi.fleet._windows import _solve

    rng = np.random.default_rng(0)
    a = rng.normal(size=(64, 20)).astype(np.float32)
    g, b = a.T @ a + 1e-3 * np.eye(20, dtype=np.float32), rng.normal(size=20).astype(np.float32)
    got = np.asarray(jax.jit(_solve)(g, b))
    want = np.linalg.solve(g.astype(float), b.astype(float))
    assert np.max(np.abs(got - want)) < 1e-4 * np.max(np.abs(want))
    hlo = jax.jit(jax.vmap(_solve)).lower(np.stack([g] * 3), np.stack([b] * 3)).as_text()
    assert "lapack" not in hlo.lower() and "custom_call" not in hlo
