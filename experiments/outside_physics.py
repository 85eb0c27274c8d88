"""Physics outside the effect library, for `concealed_effects.py --suite outside`.

Each kind changes how a recording is made; the diagnosis sees only the recording and the
vehicle file. Conventions (what is recorded is always the driver's command and the sensors):

  * torque_gain: the wheels receive 0.85 × the recorded torques (both axles);
  * rear_brake: the rear brake delivers 0.6 × its recorded (negative) torque;
  * delay: every measured channel arrives 60 ms late: y_rec(t) = y(t − 0.06 s) (an exact
    shift of the samples, the first 60 ms held at the first value; not the library's Padé);
  * gyro_scale: the yaw-rate sensor reads 1.04 × the true yaw rate;
  * body_roll: the body rolls by φ, τ·φ' + φ = k·a_y (k = 0.006 rad per m/s², τ = 0.15 s), and
    the accelerometer rolls with it: a_y,rec = a_y·cos φ + g·sin φ;
  * tyre_curve: each axle's tyre force is F_lin·tanh(x)/x with x = |F_lin|/(μ·F_z) (the
    combined linear force of Dugoff's model): nonlinear from small slip, no linear range,
    same cornering stiffness at zero slip and same limit μ·F_z as Dugoff;
  * load_sensitivity: slip and cornering stiffness grow as (F_z/F_ref)^0.75 and μ falls as
    (F_z/F_ref)^−0.1 with the load moved by longitudinal acceleration (F_ref = m·g/2; the
    constant part of the factor is absorbed by θ's stiffnesses, the load-dependent part is
    the mismatch).

The tyre kinds replace the simulator's Dugoff saturation (`_dynamics.dugoff_with_load`) for
the generation of that recording only (inside `patched_tyres`), so the diagnosing simulator
keeps Dugoff. `RIGHT` lists, per kind, the library effects and the discovered terms that
count as naming or describing the right physics.
"""

from __future__ import annotations

import contextlib

import jax
import jax.numpy as jnp
import numpy as np

import vdsbi.simulator._dynamics as _dynamics  # the generator swaps its tyre law (only here)
from vdsbi.simulator import GRAVITY, Inputs

KINDS = ("torque_gain", "rear_brake", "delay", "gyro_scale", "body_roll", "tyre_curve", "load_sensitivity")

#: kind -> (library effects, discovered terms) that count as the right physics.
RIGHT = {
    "torque_gain": ({"torque_gain"}, {"front_torque_gain", "rear_torque_gain"}),
    "rear_brake": (set(), {"rear_brake_gain", "rear_torque_gain"}),
    "delay": ({"signal_delay"}, {"steer_rate", "yaw_rate_delay"}),
    "gyro_scale": ({"sensor_scale"}, {"yaw_rate_scale"}),
    "body_roll": ({"sensor_scale"}, {"ay_scale", "ay_quadratic"}),
    "tyre_curve": (
        {"tyre_friction"},
        {"side_quadratic", "side_cubic", "steer_cubed", "yaw_moment_quadratic", "yaw_moment_cubic"},
    ),
    # the load moved by braking/accelerating changes the axles' stiffness ratio: a yaw moment
    # ∝ a_x·a_c, or the tyre nonlinearity in a_c
    "load_sensitivity": (
        set(),
        {"yaw_moment_load_transfer", "side_quadratic", "side_cubic", "steer_cubed", "side_linear"},
    ),
}

DELAY_S = 0.06
ROLL_GAIN, ROLL_TAU = 0.006, 0.15


def applied_inputs(kind: str, inputs: Inputs) -> Inputs:
    """The inputs that act on the car (the recorded ones are `inputs`)."""
    tf, tr = np.asarray(inputs.torque_front), np.asarray(inputs.torque_rear)
    if kind == "torque_gain":
        tf, tr = 0.85 * tf, 0.85 * tr
    elif kind == "rear_brake":
        tr = np.where(tr < 0, 0.6 * tr, tr)
    else:
        return inputs
    return Inputs(inputs.t0, inputs.dt, np.asarray(inputs.steer), tf, tr)


def recorded_readings(kind: str, ys: np.ndarray, dt: float) -> np.ndarray:
    """What the sensors record from the true readings ys (T, 6) (before noise)."""
    ys = np.array(ys)
    if kind == "delay":
        k = int(round(DELAY_S / dt))
        ys = np.concatenate([np.repeat(ys[:1], k, axis=0), ys[:-k]])
    elif kind == "gyro_scale":
        ys[:, 2] *= 1.04
    elif kind == "body_roll":
        ay = ys[:, 1]
        phi = np.zeros_like(ay)
        a = dt / (ROLL_TAU + dt)  # implicit Euler of τ·φ' + φ = k·a_y
        for i in range(1, len(ay)):
            phi[i] = phi[i - 1] + a * (ROLL_GAIN * ay[i] - phi[i - 1])
        ys[:, 1] = ay * np.cos(phi) + GRAVITY * np.sin(phi)
    return ys


def _tanh_tyre(demand, fz, mu):
    fx_lin, fy_lin, inv_demand = demand
    lam = mu * jnp.maximum(fz, 0.0) * inv_demand  # λ = μF_z/(2|F_lin|): x = 1/(2λ)
    x = 1.0 / (2.0 * jnp.maximum(lam, 1e-9))
    f = jnp.where(x < 1e-4, 1.0 - x**2 / 3.0, jnp.tanh(x) / jnp.maximum(x, 1e-4))
    return fx_lin * f, fy_lin * f


def _load_sensitive(original, f_ref):
    def tyre(demand, fz, mu):
        fx_lin, fy_lin, inv_demand = demand
        s = (jnp.maximum(fz, 1.0) / f_ref) ** 0.75
        mu_eff = mu * (jnp.maximum(fz, 1.0) / f_ref) ** -0.1
        return original((fx_lin * s, fy_lin * s, inv_demand / s), fz, mu_eff)

    return tyre


@contextlib.contextmanager
def patched_tyres(kind: str, mass: float):
    """Inside: the simulator uses the kind's tyre law (no change for the other kinds)."""
    original = _dynamics.dugoff_with_load
    if kind == "tyre_curve":
        _dynamics.dugoff_with_load = _tanh_tyre
    elif kind == "load_sensitivity":
        _dynamics.dugoff_with_load = _load_sensitive(original, mass * GRAVITY / 2)
    else:
        yield
        return
    jax.clear_caches()  # no trace made with the other tyre law may be reused
    try:
        yield
    finally:
        _dynamics.dugoff_with_load = original
        jax.clear_caches()
