import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import tree_allclose

from vdsbi.inference import (
    BoxPrior,
    Execution,
    IdentityEmbedding,
    NPEConfig,
    RoundSchedule,
    SplineFlowSettings,
    TrainingSettings,
    _train,
    apt,
    load_state,
    save_state,
)
from vdsbi.inference._build import build_flow
from vdsbi.inference._config import LeakPenalty, SequentialSettings, Truncation, WeightAveraging
from vdsbi.inference._loss import (
    AtomicLoss,
    MaximumLikelihoodLoss,
    atom_indices,
    atomic_apt_loss,
    leak_penalty,
)
from vdsbi.inference._theta_map import IdentityMap
from vdsbi.inference._train import init_opt_state, make_optimizer, train_step, train_steps

TINY = NPEConfig(
    flow=SplineFlowSettings(num_layers=2, num_bins=4, hidden=8),
    training=TrainingSettings(batch_size=32, max_epochs=3, patience=2),
    sequential=SequentialSettings(num_atoms=4),
)


def _with(config: NPEConfig, **fields) -> NPEConfig:
    """``config`` with each of ``fields`` set in the settings group that has it."""
    groups = {}
    for name, value in fields.items():
        group = next(g for g in ("flow", "training", "sequential") if hasattr(getattr(config, g), name))
        groups.setdefault(group, {})[name] = value
    return dataclasses.replace(
        config, **{g: dataclasses.replace(getattr(config, g), **kw) for g, kw in groups.items()}
    )


def _counted(monkeypatch, name: str, max_traces: int):
    """``_train.<name>``, as `fit` calls it, replaced by a fresh compiled copy that may be traced
    at most ``max_traces`` times (`eqx.debug.assert_max_traces`); returns the counted function."""
    counted = eqx.debug.assert_max_traces(getattr(_train, name).__wrapped__, max_traces=max_traces)
    monkeypatch.setattr(_train, name, eqx.filter_jit(counted))
    return counted


def _steps(fn):
    """A fresh compiled copy of the jitted ``fn`` that may be traced once."""
    return eqx.filter_jit(eqx.debug.assert_max_traces(fn.__wrapped__, max_traces=1))


def _gauss_sim(key, theta):
    return theta + 0.1 * jax.random.normal(key, theta.shape), jnp.ones(theta.shape[0], bool)


def test_atom_indices_distinct(getkey):
    idx = np.asarray(atom_indices(getkey(), 16, 10))
    assert idx.shape == (16, 10)
    assert np.all(idx[:, 0] == np.arange(16))
    for row in idx:
        assert len(set(row.tolist())) == 10  # distinct, hence never the row itself twice


def test_atomic_loss_hand_computed():
    theta = jnp.array([[0.1], [0.5], [-0.3]])
    x = jnp.array([[0.0], [1.0], [-1.0]])
    atoms = jnp.array([[0, 2], [1, 0], [2, 1]])

    def log_q(t, i):
        return -((t[0] - x[i, 0]) ** 2)

    def log_prior(t):  # non-constant on purpose, to check the prior correction
        return 0.5 * t[0]

    # by hand: u(θ) = -(θ - x_i)² - θ/2
    u = {
        (0, 0): -(0.1**2) - 0.05,
        (0, 2): -(0.3**2) + 0.15,
        (1, 1): -(0.5**2) - 0.25,
        (1, 0): -(0.9**2) - 0.05,
        (2, 2): -(0.7**2) + 0.15,
        (2, 1): -(1.5**2) - 0.25,
    }
    rows = [(0, 0, 2), (1, 1, 0), (2, 2, 1)]
    ll = [u[(i, a)] - np.log(np.exp(u[(i, a)]) + np.exp(u[(i, b)])) for i, a, b in rows]
    expected = -np.mean(ll)
    got = atomic_apt_loss(log_q, log_prior, theta, atoms)
    np.testing.assert_allclose(float(got), expected, rtol=1e-6)


def test_atomic_loss_module_matches_reference_kernel(getkey):
    # AtomicLoss evaluates the B·K pairs in one flat vmap; it must equal the per-row kernel.
    theta, x, flow, _ = _tiny_problem(getkey, 32)
    key = getkey()
    mask = np.arange(32) % 3 == 0
    got = AtomicLoss(num_atoms=5)(flow, theta, x, mask, key)
    want = atomic_apt_loss(
        lambda t, i: flow.log_prob(t, jnp.asarray(x)[i]),
        flow.prior.log_prob,
        jnp.asarray(theta),
        atom_indices(key, 32, 5),
    )
    np.testing.assert_allclose(float(got), float(want), rtol=1e-5)


def _as(dtype, tree):
    return jax.tree_util.tree_map(
        lambda a: a.astype(dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a, tree
    )


def _shifted_affine_flow(getkey, shift):
    """A TINY affine flow on the box [-1, 1]² whose draws sit ``shift`` to the right (some outside)."""
    theta, x, _, _ = _tiny_problem(getkey, 64)
    cfg = _with(TINY, theta_map=IdentityMap())
    flow = build_flow(getkey(), BoxPrior(-jnp.ones(2), jnp.ones(2)), IdentityEmbedding(2), theta, x, cfg.flow)
    return eqx.tree_at(lambda f: f.theta_standardizer.mean, flow, flow.theta_standardizer.mean + shift), x


def test_leak_penalty_is_the_squared_excess_of_the_flows_draws(getkey, x64):
    flow, x = _shifted_affine_flow(getkey, jnp.array([0.8, 0.0]))
    flow = _as(jnp.float64, flow)
    key, ctx = getkey(), jax.vmap(flow.context)(jnp.asarray(x[:16], jnp.float64))
    eps = jax.random.normal(key, (16, 2), dtype=jnp.float64)
    draws = np.asarray(jax.vmap(flow.unmasked_draw)(eps, ctx))
    inside = np.all(np.abs(draws) <= 1, axis=1)
    assert 0 < np.mean(inside) < 1  # some draws leak, not all
    mass = flow.box_mass(key, ctx[0], 16)  # the same base noise as draw 0's context's
    eps0 = jax.random.normal(key, (16, 2), dtype=jnp.float64)
    draws0 = np.asarray(jax.vmap(lambda e: flow.unmasked_draw(e, ctx[0]))(eps0))
    assert float(mass) == np.mean(np.all(np.abs(draws0) <= 1, axis=1))
    excess = (np.maximum(draws - 1, 0) + np.maximum(-1 - draws, 0)) / 2.0  # box width 2
    np.testing.assert_allclose(float(leak_penalty(flow, key, ctx)), np.mean(np.sum(excess**2, 1)), rtol=1e-10)

    # differentiable through the draws: d/d(shift) against central finite differences
    def pen(s):
        f = eqx.tree_at(lambda f: f.theta_standardizer.mean, flow, flow.theta_standardizer.mean + s)
        return leak_penalty(f, key, ctx)

    s0, h = jnp.zeros(2), 1e-6
    grad = jax.grad(pen)(s0)
    fd = [(pen(s0.at[j].add(h)) - pen(s0.at[j].add(-h))) / (2 * h) for j in range(2)]
    np.testing.assert_allclose(np.asarray(grad), np.asarray(fd), rtol=1e-5, atol=1e-9)
    assert grad[0] > 0  # moving the mass further right leaks more


def test_leak_penalty_is_zero_for_the_logit_map_and_adds_to_the_atomic_loss(getkey):
    theta, x, flow, _ = _tiny_problem(getkey, 32)  # TINY: a LogitMap, draws always inside
    ctx = jax.vmap(flow.context)(jnp.asarray(x))
    assert float(leak_penalty(flow, getkey(), ctx)) == 0.0
    assert float(flow.box_mass(getkey(), ctx[0], 100)) == 1.0
    affine, _ = _shifted_affine_flow(getkey, jnp.array([0.8, 0.0]))
    key, mask = getkey(), np.zeros(32, bool)
    k_atoms, k_leak = jax.random.split(key)
    plain = AtomicLoss(num_atoms=5)(affine, theta, x, mask, k_atoms)
    pen = leak_penalty(affine, k_leak, jax.vmap(affine.context)(jnp.asarray(x)))
    got = AtomicLoss(num_atoms=5, leak_weight=3.0)(affine, theta, x, mask, key)
    assert float(pen) > 0
    np.testing.assert_allclose(float(got), float(plain + 3.0 * pen), rtol=1e-5)
    # on 8 of the 32 rows: every 4th, so every device's shard gives its share
    ctx8 = jax.vmap(affine.context)(jnp.asarray(x[::4]))
    pen8 = leak_penalty(affine, k_leak, ctx8)
    got8 = AtomicLoss(num_atoms=5, leak_weight=3.0, leak_rows=8)(affine, theta, x, mask, key)
    np.testing.assert_allclose(float(got8), float(plain + 3.0 * pen8), rtol=1e-5)
    assert float(pen8) != float(pen)  # not vacuous: another set of draws
    # at an observation too: as many draws (8) at x_o's context, with their own key
    x_o = x[5]
    at = jnp.broadcast_to(affine.context(jnp.asarray(x_o)), ctx8.shape)
    pen_o = leak_penalty(affine, jax.random.fold_in(k_leak, 1), at)
    got_o = AtomicLoss(num_atoms=5, leak_weight=3.0, leak_rows=8, leak_at=x_o)(affine, theta, x, mask, key)
    assert float(pen_o) > 0
    np.testing.assert_allclose(float(got_o), float(plain + 3.0 * (pen8 + pen_o)), rtol=1e-5)


def _tiny_problem(getkey, n):
    """n prior draws with their simulations, a TINY flow built on them, and an optimiser."""
    prior = BoxPrior(-jnp.ones(2), jnp.ones(2))
    theta = np.asarray(prior.sample(getkey(), n))
    x = np.asarray(_gauss_sim(getkey(), theta)[0])
    flow = build_flow(getkey(), prior, IdentityEmbedding(2), theta, x, TINY.flow)
    return theta, x, flow, make_optimizer(TrainingSettings(learning_rate=1e-3, weight_decay=1e-4))


def test_train_step_does_not_retrace(getkey):
    theta, x, flow, opt = _tiny_problem(getkey, 256)
    state = init_opt_state(flow, opt)
    for loss in (MaximumLikelihoodLoss(), AtomicLoss(num_atoms=4)):
        step, values = _steps(train_step), []
        for i in range(4):
            batch = (theta[i * 32 : (i + 1) * 32], x[i * 32 : (i + 1) * 32], np.ones(32, bool))
            flow, state, v = step(flow, state, batch, getkey(), loss, opt)
            values.append(float(v))
        assert np.all(np.isfinite(values))


def test_scanned_epoch_equals_sequential_steps(getkey):
    # the fast path (one lax.scan per epoch) must be the same optimisation as step-by-step
    theta, x, flow0, opt = _tiny_problem(getkey, 128)
    keys = jax.random.split(getkey(), 4)
    batches = tuple(a.reshape(4, 32, *a.shape[1:]) for a in (theta, x, np.ones(128, bool)))
    for loss in (MaximumLikelihoodLoss(), AtomicLoss(num_atoms=4)):
        flow, state, values = flow0, init_opt_state(flow0, opt), []
        for i in range(4):
            flow, state, v = train_step(flow, state, tuple(b[i] for b in batches), keys[i], loss, opt)
            values.append(float(v))
        steps = _steps(train_steps)
        for _ in range(2):  # second call must reuse the trace
            flow_e, state_e, mean_e = steps(flow0, init_opt_state(flow0, opt), batches, keys, loss, opt)
        np.testing.assert_allclose(float(mean_e), np.mean(values), rtol=1e-4)
        assert tree_allclose(flow_e, flow, rtol=1e-4, atol=1e-6)


def test_weight_average_is_the_ema_of_sequential_steps(getkey):
    # the averaged flow of the scanned loop is the EMA of the step-by-step weights; padding
    # steps (live False) leave it untouched; a different decay reuses the trace
    import equinox as eqx

    from vdsbi.inference._train import trainable_filter

    theta, x, flow0, opt = _tiny_problem(getkey, 128)
    keys = jax.random.split(getkey(), 4)
    batches = tuple(a.reshape(4, 32, *a.shape[1:]) for a in (theta, x, np.ones(128, bool)))
    live = np.array([True, True, True, False])
    loss = MaximumLikelihoodLoss()
    steps = _steps(train_steps)
    for decay in (0.7, 0.9):
        flow, state = flow0, init_opt_state(flow0, opt)
        avg = eqx.filter(flow0, trainable_filter(flow0))
        for i in range(3):
            flow, state, _ = train_step(flow, state, tuple(b[i] for b in batches), keys[i], loss, opt)
            p = eqx.filter(flow, trainable_filter(flow))
            avg = jax.tree.map(lambda a, w, d=decay: d * a + (1 - d) * w, avg, p)
        out = steps(
            flow0, init_opt_state(flow0, opt), batches, keys, loss, opt, live, (flow0, jnp.asarray(decay))
        )
        assert tree_allclose(out[0], flow, rtol=1e-4, atol=1e-6)
        got = eqx.filter(out[3], trainable_filter(out[3]))
        assert tree_allclose(got, avg, rtol=1e-4, atol=1e-6)
        assert not tree_allclose(got, eqx.filter(flow, trainable_filter(flow)), rtol=1e-4, atol=1e-6)


def test_nonfinite_and_invalid_simulations_are_excluded_and_counted(getkey):
    prior = BoxPrior(-jnp.ones(2), jnp.ones(2))
    seen = {}

    def sim(key, theta):
        x = theta + 0.1 * jax.random.normal(key, theta.shape)
        x = jnp.where((theta[:, :1] > 0.5), jnp.nan, x)  # non-finite outputs
        x = jnp.where((theta[:, :1] < -0.8), jnp.inf, x)
        valid = theta[:, 1] < 0.6  # simulator-reported failures
        seen["theta"], seen["valid"] = np.asarray(theta), np.asarray(valid)
        return x, valid

    _, state = apt(
        getkey(),
        sim,
        prior,
        jnp.zeros(2),
        embedding=IdentityEmbedding(2),
        schedule=RoundSchedule(rounds=1, sims_per_round=400),
        config=TINY,
    )
    th, valid = seen["theta"], seen["valid"]
    nonfinite = (th[:, 0] > 0.5) | (th[:, 0] < -0.8)
    h = state.history[0]
    assert h["num_invalid"] == int((~valid).sum()) > 0
    assert h["num_nonfinite"] == int((valid & nonfinite).sum()) > 0
    assert h["num_used"] == int((valid & ~nonfinite).sum()) == state.theta.shape[0]
    assert state.num_invalid == 400 - h["num_used"]
    assert np.all(np.isfinite(state.x))


def test_schedule_and_execution_drive_the_rounds_and_their_callbacks(getkey):
    # One int per round, and every callback of an Execution, in the order a round runs them:
    # simulate, train epoch by epoch, then the round's end with its new state.
    prior = BoxPrior(-jnp.ones(2), jnp.ones(2))
    events = []
    execution = Execution(
        on_simulate=lambda n: events.append(("simulate", n)),
        on_epoch_end=lambda r, epoch, train, val: events.append(("epoch", r)),
        on_round_end=lambda s: events.append(("round", s.round)),
    )
    schedule = RoundSchedule(rounds=2, sims_per_round=[120, 140])
    cfg = _with(TINY, max_epochs=2, patience=5)
    _, state = apt(
        getkey(),
        _gauss_sim,
        prior,
        jnp.zeros(2),
        embedding=IdentityEmbedding(2),
        schedule=schedule,
        config=cfg,
        execution=execution,
    )
    assert [h["num_simulations"] for h in state.history] == [120, 140]
    assert events == [
        ("simulate", 120),
        ("epoch", 0),
        ("epoch", 0),
        ("round", 1),
        ("simulate", 140),
        ("epoch", 1),
        ("epoch", 1),
        ("round", 2),
    ]
    with pytest.raises(ValueError, match="2 entries for 3 rounds"):
        apt(
            getkey(),
            _gauss_sim,
            prior,
            jnp.zeros(2),
            embedding=IdentityEmbedding(2),
            schedule=dataclasses.replace(schedule, rounds=3),
            config=cfg,
        )


def test_resume_from_state_is_bit_identical(tmp_path, getkey):
    prior = BoxPrior(-jnp.ones(2), jnp.ones(2))
    cfg = _with(TINY, max_epochs=2)
    kw = dict(embedding=IdentityEmbedding(2), config=cfg)
    one, two = RoundSchedule(rounds=1, sims_per_round=200), RoundSchedule(rounds=2, sims_per_round=200)
    key, x_o = getkey(), jnp.array([0.2, -0.1])
    post_full, state_full = apt(key, _gauss_sim, prior, x_o, schedule=two, **kw)

    checkpoint = Execution(on_round_end=lambda s: save_state(tmp_path / "s.npz", s))
    apt(key, _gauss_sim, prior, x_o, schedule=one, execution=checkpoint, **kw)
    saved = load_state(tmp_path / "s.npz")
    assert saved.round == 1
    resumed = Execution(state=saved)
    post_res, state_res = apt(
        jax.random.key(999), _gauss_sim, prior, x_o, schedule=two, execution=resumed, **kw
    )

    assert state_res.history[1]["loss"] == "AtomicLoss"
    assert state_res.history[1]["box_mass"] == 1.0  # TINY's logit map keeps all mass in the box
    np.testing.assert_array_equal(state_res.theta, state_full.theta)
    np.testing.assert_array_equal(state_res.x, state_full.x)
    assert tree_allclose(post_res.flow, post_full.flow, rtol=0, atol=0)
    k = getkey()
    np.testing.assert_array_equal(np.asarray(post_res.sample(k, 100)), np.asarray(post_full.sample(k, 100)))


def test_apt_rounds_compile_a_bounded_number_of_shapes(getkey, monkeypatch):
    # Growing data between rounds must not recompile the step: the scanned blocks have one
    # length (padding steps are masked), and a second run with the same shapes reuses every
    # trace (the regression test optax/blackjax keep for their steps).
    prior = BoxPrior(-jnp.ones(2), jnp.ones(2))
    cfg = _with(TINY, max_epochs=2)
    schedule = RoundSchedule(rounds=3, sims_per_round=[150, 170, 190])
    kw = dict(embedding=IdentityEmbedding(2), schedule=schedule, config=cfg)
    # one trace per loss (ML in round 1, atomic after): blocks have one padded length
    counted = [_counted(monkeypatch, "train_steps", 2), _counted(monkeypatch, "eval_steps", 3)]
    apt(getkey(), _gauss_sim, prior, jnp.zeros(2), **kw)
    first = [eqx.debug.get_num_traces(f) for f in counted]
    apt(getkey(), _gauss_sim, prior, jnp.array([0.3, -0.2]), **kw)
    assert [eqx.debug.get_num_traces(f) for f in counted] == first


@pytest.mark.parametrize("averaging", [None, WeightAveraging(epochs=1.0)])
def test_npe_on_given_simulations_learns_and_checks_shapes(averaging, getkey):
    from vdsbi.inference import npe

    prior = BoxPrior(-jnp.ones(2), jnp.ones(2))
    theta = np.asarray(prior.sample(getkey(), 512))
    x = np.asarray(_gauss_sim(getkey(), theta)[0])
    cfg = _with(TINY, max_epochs=8, averaging=averaging)
    flow, info = npe(getkey(), prior, theta, x, embedding=IdentityEmbedding(2), config=cfg)
    assert info["epochs"] <= 8 and np.all(np.isfinite(info["val_losses"]))
    # trained: the validation loss ends below where it started (x = θ + small noise is informative)
    assert info["best_val_loss"] < info["val_losses"][0]
    with pytest.raises(ValueError, match="need theta"):
        npe(getkey(), prior, theta[:, :1], x, embedding=IdentityEmbedding(2), config=TINY)


@pytest.mark.parametrize("over_new_data", [True, False])
def test_later_rounds_wait_for_their_new_data_only(over_new_data, getkey):
    # Over new data: after a round that stopped early, round r of equal rounds waits
    # ceil(p / (r + 1)) epochs (at least 2); after one cut off by max_epochs, p. Otherwise p
    # epochs in every round. Either way a round stops exactly `patience` epochs after its best
    # one, unless it ran out of epochs.
    prior = BoxPrior(-jnp.ones(2), jnp.ones(2))
    cfg = _with(TINY, max_epochs=40, patience=6, patience_over_new_data=over_new_data)
    _, state = apt(
        getkey(),
        _gauss_sim,
        prior,
        jnp.zeros(2),
        embedding=IdentityEmbedding(2),
        schedule=RoundSchedule(rounds=4, sims_per_round=160),
        config=cfg,
    )
    hist = state.history
    for r, h in enumerate(hist):
        scaled = over_new_data and r > 0 and hist[r - 1]["epochs"] < 40
        assert h["patience"] == (max(2, -(-6 // (r + 1))) if scaled else 6)
        assert h["epochs"] == 40 or h["epochs"] - 1 - h["best_epoch"] == h["patience"]
    if over_new_data:  # the data made some round stop early and the next one scale
        assert min(h["patience"] for h in hist) < 6


def test_cosine_schedule_runs_its_course_without_recompiling(getkey, monkeypatch):
    # The learning rate lives in the optimiser state: a new value every epoch reuses the
    # compiled step. A round that ran its whole cosine schedule counts as converged, so the
    # next round scales its patience as after an early stop; that round continues the trained
    # flow at the constant rate.
    prior = BoxPrior(-jnp.ones(2), jnp.ones(2))
    cfg = _with(TINY, max_epochs=4, patience=6, cosine_decay=True)
    _counted(monkeypatch, "train_steps", 2)  # one per loss, not one per epoch
    kw = dict(
        embedding=IdentityEmbedding(2), schedule=RoundSchedule(rounds=2, sims_per_round=160), config=cfg
    )
    _, state = apt(getkey(), _gauss_sim, prior, jnp.zeros(2), **kw)
    first, second = state.history
    assert first["epochs"] == 4  # patience 6 > 4 epochs: no early stop
    assert second["patience"] == 3  # ceil(6 / 2), not the full 6 of an unconverged round
    assert (first["cosine_decay"], second["cosine_decay"]) == (True, False)


def test_later_rounds_are_capped_in_passes_over_their_new_data(getkey):
    # later_max_epochs=8 over equal rounds: round r (from 0) runs at most round(8 / (r + 1))
    # epochs (at least 2), so each later round sees about the same number of examples; a round
    # cut off by its cap has not converged, so the next one waits the full patience.
    prior = BoxPrior(-jnp.ones(2), jnp.ones(2))
    cfg = _with(TINY, max_epochs=5, patience=10, later_max_epochs=8)
    kw = dict(
        embedding=IdentityEmbedding(2), schedule=RoundSchedule(rounds=4, sims_per_round=160), config=cfg
    )
    _, state = apt(getkey(), _gauss_sim, prior, jnp.zeros(2), **kw)
    assert [h["max_epochs"] for h in state.history] == [5, 4, 3, 2]
    assert [h["epochs"] for h in state.history] == [5, 4, 3, 2]  # patience 10: no early stop
    assert [h["patience"] for h in state.history] == [10, 10, 10, 10]
    with pytest.raises(ValueError, match="later_max_epochs"):
        SequentialSettings(later_max_epochs=0)


def test_config_fields_are_checked():
    with pytest.raises(TypeError, match="theta_map"):
        SplineFlowSettings(theta_map="logit")
    with pytest.raises(TypeError, match="x_standardize"):
        SplineFlowSettings(x_standardize="channel")
    with pytest.raises(TypeError, match="flow"):
        NPEConfig(flow=TrainingSettings())
    with pytest.raises(ValueError, match="epochs"):
        WeightAveraging(epochs=-1.0)
    with pytest.raises(TypeError, match="averaging"):
        TrainingSettings(averaging=1.0)
    with pytest.raises(ValueError, match="weight"):
        LeakPenalty(weight=-0.1)
    with pytest.raises(ValueError, match="rows"):
        LeakPenalty(weight=1.0, rows=-1)
    with pytest.raises(TypeError, match="leak"):
        SequentialSettings(leak=10.0)
    with pytest.raises(ValueError, match="epsilon"):
        Truncation(epsilon=0.0)


def test_fit_takes_an_optax_optimizer(getkey):
    # `fit` trains with the optimiser it is given; a schedule needs an injected learning rate
    import optax

    from vdsbi.inference._train import Examples, fit

    theta, x, flow, _ = _tiny_problem(getkey, 128)
    data = Examples(theta, x, np.ones(128, bool), np.arange(128) % 8 == 0)
    training = TrainingSettings(batch_size=32, max_epochs=2, patience=2)
    loss, key = MaximumLikelihoodLoss(), getkey()
    default, _ = fit(key, flow, data, loss, training)
    same, _ = fit(key, flow, data, loss, training, make_optimizer(training))
    assert tree_allclose(default, same, rtol=0, atol=0)
    sgd, info = fit(key, flow, data, loss, training, optax.sgd(1e-2))
    assert info["epochs"] == 2 and not tree_allclose(sgd, default)
    cosine = dataclasses.replace(training, cosine_decay=True)
    with pytest.raises(ValueError, match="inject_hyperparams"):
        fit(key, flow, data, loss, cosine, optax.sgd(1e-2))


def test_eval_steps_ignores_padding_batches(getkey):
    # padding batches (live=False, skipped) cannot change the validation loss
    from vdsbi.inference._train import eval_steps

    theta, x, flow, _ = _tiny_problem(getkey, 128)
    batches = tuple(a.reshape(4, 32, *a.shape[1:]) for a in (theta, x, np.ones(128, bool)))
    live = np.array([True, True, False, False])
    junk = tuple(
        np.concatenate([b[:2], np.full_like(b[2:], np.nan if b.dtype != bool else True)]) for b in batches
    )
    loss, key = MaximumLikelihoodLoss(), getkey()
    want = np.mean([float(loss(flow, *(b[i] for b in batches), key)) for i in range(2)])
    np.testing.assert_allclose(float(eval_steps(flow, junk, key, loss, live)), want, rtol=1e-5)
    np.testing.assert_allclose(
        float(eval_steps(flow, batches, key, loss)),
        np.mean([float(loss(flow, *(b[i] for b in batches), key)) for i in range(4)]),
        rtol=1e-5,
    )


def test_build_flow_weights_equal_the_op_by_op_build(getkey):
    # the initialisation is compiled with CPU-specific XLA options; the weights must be the
    # ones the same program gives at XLA's default level (3; explicit, since the tests' own
    # XLA_FLAGS lower it), bit for bit
    import vdsbi.inference._build as build_module

    theta, x, flow, _ = _tiny_problem(getkey, 64)
    key = getkey()
    got = build_flow(key, flow.prior, IdentityEmbedding(2), theta, x, TINY.flow)
    orig = build_module._INIT_CPU_OPTIONS
    build_module._init_program.cache_clear()
    try:
        build_module._INIT_CPU_OPTIONS = {"xla_backend_optimization_level": 3}
        want = build_flow(key, flow.prior, IdentityEmbedding(2), theta, x, TINY.flow)
    finally:
        build_module._INIT_CPU_OPTIONS = orig
        build_module._init_program.cache_clear()
    assert jax.tree.structure(got) == jax.tree.structure(want)
    assert tree_allclose(got, want, rtol=0, atol=0)


def test_build_flow_compiles_its_initialisation_once_per_structure(getkey):
    # cached on the static structure, so a second build of the same shapes compiles nothing; an
    # embedding holding an unhashable value still builds (uncached), with the same weights
    import types

    import equinox as eqx

    import vdsbi.inference._build as build_module

    theta, x, flow, _ = _tiny_problem(getkey, 64)
    key = getkey()
    first = build_flow(key, flow.prior, IdentityEmbedding(2), theta, x, TINY.flow)
    misses = build_module._init_program.cache_info().misses
    again = build_flow(key, flow.prior, IdentityEmbedding(2), theta, x, TINY.flow)
    assert build_module._init_program.cache_info().misses == misses
    assert tree_allclose(first, again, rtol=0, atol=0)

    class Tagged(IdentityEmbedding):
        tag: types.SimpleNamespace  # defines __eq__, so unhashable

        def __init__(self, dim, tag):
            super().__init__(dim)
            self.tag = tag

    odd = build_flow(key, flow.prior, Tagged(2, types.SimpleNamespace()), theta, x, TINY.flow)
    assert build_module._init_program.cache_info().misses == misses
    assert tree_allclose(eqx.filter(odd, eqx.is_array), eqx.filter(first, eqx.is_array), rtol=0, atol=0)


def test_npe_on_a_new_data_size_reuses_the_compiled_loops(getkey, monkeypatch):
    # steps run in fixed-length padded blocks and validation in padded blocks (compiled on a
    # worker thread): a second NPE on more simulations traces neither loop again
    from vdsbi.inference import npe

    prior = BoxPrior(-jnp.ones(2), jnp.ones(2))
    cfg = _with(TINY, max_epochs=2)
    for name in ("train_steps", "eval_steps"):
        _counted(monkeypatch, name, 1)
    for n in (400, 520):
        theta = np.asarray(prior.sample(getkey(), n))
        x = np.asarray(_gauss_sim(getkey(), theta)[0])
        npe(getkey(), prior, theta, x, embedding=IdentityEmbedding(2), config=cfg)


def test_penalty_at_the_observation_keeps_more_of_its_posterior_in_the_box(getkey):
    # x_o near the box's corner: the flow on θ puts some of q(θ | x_o) outside, and the
    # batch's contexts (the proposal's) see little of it. The same run (same key: same first
    # round) with the penalty at x_o as well must leave more of the posterior in the box.
    prior = BoxPrior(-jnp.ones(2), jnp.ones(2))
    key, x_o = getkey(), jnp.array([0.95, 0.95])
    mass = {}
    for at in (False, True):
        cfg = _with(
            TINY,
            theta_map=IdentityMap(),
            leak=LeakPenalty(weight=10.0, rows=8, at_observation=at),
            max_epochs=20,
            patience=20,
        )
        _, state = apt(
            key,
            _gauss_sim,
            prior,
            x_o,
            embedding=IdentityEmbedding(2),
            schedule=RoundSchedule(rounds=2, sims_per_round=300),
            config=cfg,
        )
        mass[at] = float(state.flow.box_mass(jax.random.key(0), state.flow.context(x_o), 20_000))
    assert 0.5 < mass[False] < 0.99
    assert mass[True] > mass[False] + 0.01  # measured: +0.021 to +0.024 over three seeds
