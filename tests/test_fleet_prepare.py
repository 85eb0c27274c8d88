"""A platform's preparation: an estimator that did not train is no estimator."""

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
