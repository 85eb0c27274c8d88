"""Candidate terms for physics outside the effect library, and an effect made of a few of them.

Each term adds c·f(signals) to one place of the model: the acting steer or axle torques (an
input term), the force or the yaw moment on the body (per unit mass: c·m·f is the force, N, or
the moment, N·m), or one sensor reading. f is built from the model's own signals — speeds,
accelerations, yaw rate and its derivative, steer and its rate, torques — with powers, signs
and products; a rate stands for a delayed copy (x(t − d) ≈ x − d·ẋ). Discovery fits the
coefficients c through the differentiable simulator like any effect parameter
(`term_effect(keys)` is an effect class whose parameters are the chosen terms' c, all 0 at the
null), and prints the term as a formula.

The library is deliberately not registered in `EFFECTS`: it is searched by sparse selection
when the named effects leave a mismatch (`vdsbi.discovery`), not one effect at a time.
"""

from typing import Literal, NamedTuple

import jax.numpy as jnp

from ._base import AbstractEffect, Param

#: Time constant of the filter whose output gives the steer rate (δ − δ_f)/τ, s.
RATE_FILTER_TAU = 0.02


#: Where a term acts: an input, a force or moment on the body, or a sensor reading.
Target = Literal[
    "steer", "torque_front", "torque_rear", "force_x", "force_y", "moment_z", "ax", "ay", "yaw_rate"
]


class Term(NamedTuple):
    """One candidate: `target` is where c·f enters, `feature` the formula of f, `unit` c's unit,
    `bound` the largest |c| fitted."""

    target: Target
    feature: str
    unit: str
    bound: float


#: The candidate terms. Signals: δ steer (rad), δ̇ its rate, T_f, T_r axle torques (N·m), vx, vy
#: (m/s), r yaw rate (rad/s), ṙ its rate, a_c = vx·r (m/s²), ax, ay the modelled accelerations.
#: Forces and the yaw moment are per unit mass: c·m·f is the force (N) or moment (N·m).
TERMS: dict[str, Term] = {
    "steer_gain": Term("steer", "δ", "-", 2.0),
    "steer_cubed": Term("steer", "δ³", "1/rad²", 800.0),
    "steer_rate": Term("steer", "δ̇", "s", 0.5),
    "front_torque_gain": Term("torque_front", "T_f", "-", 1.5),
    "rear_torque_gain": Term("torque_rear", "T_r", "-", 1.5),
    "rear_brake_gain": Term("torque_rear", "min(T_r, 0)", "-", 1.5),
    "drag_constant": Term("force_x", "1", "m/s²", 3.0),
    "drag_speed_squared": Term("force_x", "vx²", "1/m", 0.01),
    "drag_cornering": Term("force_x", "a_c²", "s²/m", 0.2),
    "side_constant": Term("force_y", "1", "m/s²", 3.0),
    "side_linear": Term("force_y", "a_c", "-", 1.0),
    "side_quadratic": Term("force_y", "a_c·|a_c|", "s²/m", 0.2),
    "side_cubic": Term("force_y", "a_c³", "s⁴/m²", 0.04),
    "side_slip": Term("force_y", "vy", "1/s", 5.0),
    # yaw moment per unit mass (c·f in m²/s²): uneven axle saturation, load-sensitive tyres
    "yaw_moment_linear": Term("moment_z", "a_c", "m", 0.5),
    "yaw_moment_quadratic": Term("moment_z", "a_c·|a_c|", "s²", 0.1),
    "yaw_moment_cubic": Term("moment_z", "a_c³", "s⁴/m", 0.02),
    "yaw_moment_load_transfer": Term("moment_z", "ax·a_c", "s²", 0.2),
    "yaw_damping": Term("moment_z", "r", "m²/s", 5.0),
    "ay_scale": Term("ay", "ay", "-", 0.5),
    "ay_quadratic": Term("ay", "ay·|ay|", "s²/m", 0.2),
    "ay_yaw_accel": Term("ay", "ṙ", "m", 3.0),
    "ay_from_ax": Term("ay", "ax", "-", 0.3),
    "ay_offset": Term("ay", "1", "m/s²", 3.0),
    "ax_scale": Term("ax", "ax", "-", 0.5),
    "ax_from_ay": Term("ax", "ay", "-", 0.3),
    "ax_centripetal": Term("ax", "r²", "m", 5.0),
    "ax_offset": Term("ax", "1", "m/s²", 3.0),
    "yaw_rate_scale": Term("yaw_rate", "r", "-", 0.5),
    "yaw_rate_delay": Term("yaw_rate", "ṙ", "s", 0.5),
    "yaw_rate_offset": Term("yaw_rate", "1", "rad/s", 0.1),
}


def _feature(name: str, sig: dict):
    """f of term `name` from the signals available where it enters."""
    t = TERMS[name]
    f = t.feature
    if f == "1":
        return jnp.ones_like(next(iter(sig.values())))
    table = {
        "δ": lambda: sig["steer"],
        "δ³": lambda: sig["steer"] ** 3,
        "δ̇": lambda: sig["steer_rate"],
        "T_f": lambda: sig["torque_front"],
        "T_r": lambda: sig["torque_rear"],
        "min(T_r, 0)": lambda: jnp.minimum(sig["torque_rear"], 0.0),
        "vx²": lambda: sig["vx"] ** 2,
        "a_c": lambda: sig["vx"] * sig["r"],
        "a_c²": lambda: (sig["vx"] * sig["r"]) ** 2,
        "a_c·|a_c|": lambda: sig["vx"] * sig["r"] * jnp.abs(sig["vx"] * sig["r"]),
        "a_c³": lambda: (sig["vx"] * sig["r"]) ** 3,
        "vy": lambda: sig["vy"],
        "ax·a_c": lambda: sig["ax"] * sig["vx"] * sig["r"],
        "ay": lambda: sig["ay"],
        "ay·|ay|": lambda: sig["ay"] * jnp.abs(sig["ay"]),
        "ax": lambda: sig["ax"],
        "ṙ": lambda: sig["r_dot"],
        "r": lambda: sig["r"],
        "r²": lambda: sig["r"] ** 2,
    }
    return table[f]()


class _TermEffect(AbstractEffect):
    """c·f for the terms in `params` (set by `term_effect`)."""

    name = "discovered_terms"
    params = ()
    description = "terms outside the library, found by sparse selection"
    num_states = 1  # the filtered steer, for δ̇

    def init_state(self, p, u0):
        return u0[:1]

    def state_rhs(self, p, z, u_cmd):
        return (u_cmd[:1] - z) / RATE_FILTER_TAU

    def _sum(self, p, target, sig):
        out = 0.0
        for k, name in enumerate(self.param_names):
            if TERMS[name].target == target:
                out = out + p[k] * _feature(name, sig)
        return out

    def inputs(self, p, z, u):
        sig = {"steer": u[0], "steer_rate": (u[0] - z[0]) / RATE_FILTER_TAU}
        sig.update(torque_front=u[1], torque_rear=u[2])
        add = [self._sum(p, tgt, sig) for tgt in ("steer", "torque_front", "torque_rear")]
        return u + jnp.stack([jnp.asarray(a, u.dtype) * jnp.ones_like(u[0]) for a in add])

    def body_force(self, p, ctx):
        sig = {"vx": ctx.vx, "vy": ctx.vy, "r": ctx.r}
        fx = ctx.mass * self._sum(p, "force_x", sig)
        fy = ctx.mass * self._sum(p, "force_y", sig)
        return jnp.asarray(fx) * jnp.ones_like(ctx.vx), jnp.asarray(fy) * jnp.ones_like(ctx.vx)

    def yaw_moment(self, p, ctx):
        sig = {"vx": ctx.vx, "vy": ctx.vy, "r": ctx.r, "ax": ctx.ax}
        return jnp.asarray(ctx.mass * self._sum(p, "moment_z", sig)) * jnp.ones_like(ctx.vx)

    def measure(self, p, y, ctx):
        sig = {"ax": y["ax"], "ay": y["ay"], "r": y["yaw_rate"], "r_dot": ctx.r_dot}
        y = dict(y)
        for ch in ("ax", "ay", "yaw_rate"):
            y[ch] = y[ch] + self._sum(p, ch, sig)
        return y


def term_effect(keys) -> type[AbstractEffect]:
    """An effect class adding the terms `keys` (names in `TERMS`), one coefficient each."""
    keys = tuple(keys)
    unknown = [k for k in keys if k not in TERMS]
    if unknown:
        raise ValueError(f"term_effect: unknown term(s) {unknown} (known: {', '.join(TERMS)})")
    params = tuple(
        Param(k, TERMS[k].unit, null=0.0, typical=(-b / 5, b / 5), bounds=(-b, b), start=0.0)
        for k, b in ((k, TERMS[k].bound) for k in keys)
    )
    attrs = {"name": "discovered_terms", "params": params}
    return type("DiscoveredTerms", (_TermEffect,), attrs)


#: How each target reads in a formula.
_TARGET_TEXT = {
    "steer": "acting steer δ += {c}·{f}",
    "torque_front": "applied front torque T_f += {c}·{f}",
    "torque_rear": "applied rear torque T_r += {c}·{f}",
    "force_x": "longitudinal force += {c}·m·{f}",
    "force_y": "lateral force += {c}·m·{f}",
    "moment_z": "yaw moment += {c}·m·{f}",
    "ax": "ax measured as ax + {c}·{f}",
    "ay": "ay measured as ay + {c}·{f}",
    "yaw_rate": "yaw_rate measured as yaw_rate + {c}·{f}",
}


def term_formula(key: str, c: float) -> str:
    """The term as a formula, e.g. 'lateral force += -0.031·m·a_c·|a_c| (c in s²/m)'."""
    t = TERMS[key]
    text = _TARGET_TEXT[t.target].format(c=f"{c:+.4g}", f=t.feature)
    if t.feature == "1":
        text = text.replace("·m·1", "·m").replace("·1", "")
    text = text.replace("+= +", "+= ").replace("+ +", "+ ").replace("+ -", "− ")
    return f"{text} (c in {t.unit})"
