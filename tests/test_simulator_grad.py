"""jax.grad through the solver matches central finite differences for θ and every effect
parameter (float64)."""

import jax
import jax.numpy as jnp
import numpy as np

from vdsbi.simulator import (
    PARAM_NAMES,
    SEED_TRUE_THETA,
    SeedManeuver,
    default_vehicle,
    make_model,
    seed_profile,
    solve,
)
from vdsbi.simulator.effects import EFFECTS, effect_params_from
from vdsbi.simulator.solvers import Solver

NAMES = tuple(EFFECTS)[:10]


def test_grad_matches_central_differences(x64, getkey):
    vehicle = default_vehicle()
    model = make_model(vehicle, NAMES)
    # 1 s with a gas-to-brake switch at 0.5 s and half a steer period: every parameter acts
    inputs = seed_profile(1.0, maneuver=SeedManeuver(torque_period=1.0, steer_period=1.0))
    # every effect on, at a non-null point inside its typical range
    values = {
        cls.name: {p: lo + 0.7 * (hi - lo) for p, (lo, hi) in zip(cls.param_names, cls.typical)}
        for cls in (EFFECTS[n] for n in NAMES)
    }
    _, params = effect_params_from(NAMES, values)
    sizes = [p.shape[0] for p in params]
    x0 = jnp.concatenate([jnp.array([SEED_TRUE_THETA[n] for n in PARAM_NAMES]), *params])
    # scale of each coordinate for the finite-difference step
    scale = jnp.concatenate([x0[:6], *[jnp.array([hi - lo for lo, hi in EFFECTS[n].typical]) for n in NAMES]])
    weights = jax.random.normal(getkey(), (inputs.num_samples, 6), dtype=x0.dtype)

    def loss(x):
        theta, rest = x[:6], x[6:]
        ps, i = [], 0
        for k in sizes:
            ps.append(rest[i : i + k])
            i += k
        ys, _ = solve(model, theta, inputs, jnp.asarray(10.5), tuple(ps), Solver(dt=0.005))
        # a weighted trajectory functional, each channel normalised by its magnitude
        return jnp.mean(weights * ys / (jnp.abs(ys).mean(0) + 1e-3))

    # one compilation serves the gradient and all the finite-difference evaluations
    value_and_grad = jax.jit(jax.value_and_grad(loss))
    grad = np.asarray(value_and_grad(x0)[1])
    h = 1e-5 * np.asarray(scale)
    fd = np.array(
        [
            (float(value_and_grad(x0.at[i].add(h[i]))[0]) - float(value_and_grad(x0.at[i].add(-h[i]))[0]))
            / (2 * h[i])
            for i in range(x0.shape[0])
        ]
    )
    names = list(PARAM_NAMES) + [f"{e}.{p}" for e in NAMES for p in EFFECTS[e].param_names]
    # per coordinate, sensitivities compared on a common scale (d loss / d log-scale)
    scaled_g, scaled_fd = grad * np.asarray(scale), fd * np.asarray(scale)
    assert np.all(np.abs(scaled_fd) > 1e-7), dict(zip(names, scaled_fd))  # none is trivially 0
    rel = np.abs(scaled_g - scaled_fd) / np.abs(scaled_fd)
    assert np.all(rel < 1e-4), {k: v for k, v in zip(names, rel) if v >= 1e-4}
