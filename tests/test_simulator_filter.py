"""The anti-alias Decimator: pass band, stop band, edges, gradients, shapes, numpy = jax, and
the StochasticSimulator applying it after the sensor noise."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdsbi.simulator import PARAM_NAMES, SEED_TRUE_THETA, default_vehicle, make_model, seed_profile
from vdsbi.simulator.measurement import Decimator, SensorNoise, StochasticSimulator

RATE, CUTOFF, FACTOR = 200.0, 10.0, 4
T = np.arange(2001) / RATE


def sine(freq, phase=0.3):
    return np.sin(2 * np.pi * freq * T + phase)


def test_pass_band_within_one_percent(x64):
    dec = Decimator(RATE, CUTOFF, FACTOR)
    e = dec.edge_samples
    for phase in np.linspace(0, 2 * np.pi, 9):
        x = sine(CUTOFF / 5, phase)
        err = np.abs(np.asarray(dec(x)) - x[::FACTOR])
        assert err[e:-e].max() < 0.01  # measured 6.8e-4
        x = sine(CUTOFF / 10, phase)
        err = np.abs(np.asarray(dec(x)) - x[::FACTOR])
        assert err.max() < 0.01  # edges included (odd reflection); measured 1.7e-3


def test_stop_band_beyond_thirty_db(x64):
    dec = Decimator(RATE, CUTOFF, FACTOR)
    e = dec.edge_samples
    y = np.asarray(dec(sine(3 * CUTOFF)))
    gain_db = lambda v: 10 * np.log10(np.mean(v**2) / 0.5)
    assert gain_db(y[e:-e]) < -30  # measured −67 dB
    # Edges included: the end sample weighs heavily there (≈ −31 to −35 dB).
    assert gain_db(y) < -30


def test_constants_and_ramps_pass_exactly_edges_included(x64):
    dec = Decimator(RATE, CUTOFF, FACTOR)
    np.testing.assert_allclose(dec(np.full(301, 2.5)), 2.5, rtol=1e-14)
    ramp = 3.0 + 0.5 * T
    np.testing.assert_allclose(dec(ramp), ramp[::FACTOR], rtol=1e-13)


def test_shapes_times_and_numpy_equals_jax(getkey):
    dec = Decimator(RATE, CUTOFF, FACTOR)
    assert dec.num_taps % 2 == 1 and abs(dec.taps.sum() - 1) < 1e-12
    np.testing.assert_array_equal(dec.taps, dec.taps[::-1])  # linear (zero) phase
    assert dec.output_rate == RATE / FACTOR
    for n in (dec.half_length + 1, 401, 402, 403, 404):
        x = np.asarray(jax.random.normal(getkey(), (n, 3)), dtype=np.float32)
        y = dec(x)
        assert y.shape == (dec.num_out(n), 3) == (len(range(0, n, FACTOR)), 3)
        assert dec.output_times(np.arange(n) / RATE).shape == (dec.num_out(n),)
        np.testing.assert_array_equal(np.asarray(y), np.asarray(dec(jnp.asarray(x))))
        assert y.dtype == jnp.float32
        np.testing.assert_array_equal(np.asarray(dec(x[:, 1])), np.asarray(y[:, 1]))
    np.testing.assert_allclose(dec.output_times(T), T[::FACTOR])
    x = jax.random.normal(getkey(), (5, 401, 2))
    batched = jax.jit(jax.vmap(dec))(x)
    np.testing.assert_allclose(batched[3], dec(x[3]), rtol=1e-5, atol=1e-6)
    assert Decimator(RATE, CUTOFF).num_out(401) == 401  # factor 1: filter only


def test_gradients_flow(x64, getkey):
    dec = Decimator(RATE, CUTOFF, FACTOR)
    x = jax.random.normal(getkey(), (200,))
    w = jax.random.normal(getkey(), (dec.num_out(200),))
    jac = jax.jacfwd(dec)(x)  # the operator is linear: its matrix
    np.testing.assert_allclose(jax.grad(lambda x: jnp.dot(w, dec(x)))(x), jac.T @ w, rtol=1e-10)
    np.testing.assert_allclose(jac @ x, dec(x), rtol=1e-10, atol=1e-12)


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="cutoff"):
        Decimator(RATE, 30.0, FACTOR)  # above the output Nyquist rate 25 Hz
    with pytest.raises(ValueError, match="factor"):
        Decimator(RATE, CUTOFF, 0)
    dec = Decimator(RATE, CUTOFF, FACTOR)
    with pytest.raises(ValueError, match="too few"):
        dec(np.zeros(dec.half_length))
    assert dec(np.zeros(dec.half_length + 1)).shape == (dec.num_out(dec.half_length + 1),)


def test_stochastic_simulator_filters_the_noise(getkey):
    vehicle = default_vehicle()
    inputs = seed_profile(1.0)
    theta = jnp.tile(jnp.array([SEED_TRUE_THETA[n] for n in PARAM_NAMES]), (3, 1))
    dec = Decimator(RATE, CUTOFF, FACTOR)
    plain = StochasticSimulator(
        model=make_model(vehicle),
        inputs=inputs,
        channels=("ay", "yaw_rate"),
        v0_range=(10.0, 11.0),
        sensor_noise=SensorNoise.seed(),
    )
    decimating = StochasticSimulator(
        model=plain.model,
        inputs=inputs,
        channels=plain.channels,
        v0_range=plain.v0_range,
        sensor_noise=plain.sensor_noise,
        decimator=dec,
    )
    key = getkey()
    ys, ok = plain(key, theta)
    yd, okd = decimating(key, theta)
    assert yd.shape == (3, dec.num_out(inputs.num_samples), 2) and bool(okd.all() & ok.all())
    # Same key, same noisy draw: decimating afterwards is the same operator.
    np.testing.assert_allclose(yd, jax.vmap(dec)(ys), rtol=1e-5, atol=1e-6)
    # The noise is filtered: less scatter around a smooth trajectory than before.
    assert np.std(np.diff(np.asarray(yd[0, :, 0]))) < 0.5 * np.std(np.diff(np.asarray(ys[0, ::FACTOR, 0])))


def test_stochastic_simulator_lateral0_field_and_argument(getkey):
    inputs = seed_profile(0.5)
    theta = jnp.tile(jnp.array([SEED_TRUE_THETA[n] for n in PARAM_NAMES]), (2, 1))
    lateral0 = jnp.array([[0.1, 0.05], [-0.2, -0.1]])
    kwargs = dict(
        model=make_model(default_vehicle()),
        inputs=inputs,
        channels=("yaw_rate", "ay"),
        v0_range=(10.0, 11.0),
        sensor_noise=SensorNoise.none(),
    )
    key = getkey()
    fixed, _ = StochasticSimulator(**kwargs, lateral0=lateral0)(key, theta)
    given, _ = StochasticSimulator(**kwargs)(key, theta, lateral0=lateral0)
    straight, _ = StochasticSimulator(**kwargs)(key, theta)
    np.testing.assert_array_equal(fixed, given)
    np.testing.assert_allclose(fixed[:, 0, 0], lateral0[:, 1])  # the first yaw rate is r0
    assert np.all(straight[:, 0, 0] == 0)
