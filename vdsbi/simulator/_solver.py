"""Integrators as solver objects: fixed-step RK4 (the default) and adaptive Tsit5."""

from __future__ import annotations

import abc

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ._dynamics import AbstractVehicleModel, Args


class AbstractSolver(eqx.Module):
    """How to integrate a model over its input samples."""

    @abc.abstractmethod
    def integrate(
        self, model: AbstractVehicleModel, y0: Float[Array, " S"], args: Args
    ) -> tuple[Float[Array, "T 6"], Bool[Array, ""]]:
        """Readings at `args.inputs.ts` from the state y0 at `args.inputs.t0`, and whether the
        integration succeeded."""

    def batched(self) -> AbstractSolver:
        """The same integrator laid out for many draws at once (default: itself)."""
        return self


class RK4(AbstractSolver):
    """Fixed-step classical RK4, stepped with `lax.scan`, so a batch has a static cost and
    readings land exactly on the samples.

    The default 2.5 ms is two steps per 200 Hz sample. One step per sample (5 ms) is stable
    and 4th-order accurate too, but its ax error at torque steps (≈ 0.025 m/s² in float32)
    exceeds a tenth of the seed's sensor noise; 2.5 ms brings it to ≈ 0.002 m/s² for twice
    the cost. The wheel/slip-relaxation pair is a lightly damped oscillator with
    ω_n² ≈ C_κ·R_eff²/(I_w·σ_l) (≈ 170 rad/s for the default car, 270 rad/s at the prior's
    stiffest tires): |λ|·h ≤ 1.4 at h = 5 ms, inside RK4's stability region (2.8 on the
    imaginary axis), so no implicit solver is needed.

    Attributes:
        dt: step, s, rounded to an integer fraction of the sample interval.
        unroll: write the four stages out in the program (`batched`, what `solve_batch`
            uses): a batched step costs about 1.5× less on a CPU, for a program that takes
            2–3× longer to trace and compile. Otherwise one loop runs over the stages and
            substeps, so the model's vector field appears once: the layout of the fits, their
            derivatives and a problem's draws, where compiling dominates.
    """

    dt: float = eqx.field(static=True, default=0.0025)
    unroll: bool = eqx.field(static=True, default=False)

    def batched(self) -> RK4:
        return RK4(self.dt, unroll=True)

    def __check_init__(self):
        if not self.dt > 0:
            raise ValueError(f"solver: dt must be > 0, got {self.dt!r}")

    def integrate(self, model, y0, args):
        inputs = args.inputs
        substeps = max(1, round(inputs.dt / self.dt))
        h = inputs.dt / substeps
        # Classical RK4 in plain jnp (both autodiff modes work through it).
        f = lambda t, y: model.vector_field(t, y, args)

        def rk4_step(t0, y, k1):
            k2 = f(t0 + 0.5 * h, y + (0.5 * h) * k1)
            k3 = f(t0 + 0.5 * h, y + (0.5 * h) * k2)
            k4 = f(t0 + h, y + h * k3)
            return y + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

        def unrolled(t_k, y, k1):
            y = rk4_step(t_k, y, k1)
            if substeps > 1:  # the substeps in a loop: no slower than written out
                step = lambda j, y: rk4_step(t_k + j * h, y, f(t_k + j * h, y))
                y = jax.lax.fori_loop(1, substeps, step, y)
            return y

        def rolled(t_k, y, k1):
            nodes = jnp.array([0.0, 0.5, 0.5, 1.0])
            weights = jnp.array([1.0, 2.0, 2.0, 1.0])

            def stage(i, carry):
                # Stage s of substep j; `y_j` is the state at the substep's start.
                y_j, acc, k_prev = carry
                j, s = i // 4, i % 4
                c = nodes[s] * h
                k_s = f(t_k + j * h + c, y_j + c * k_prev)
                acc = jnp.where(s == 0, 0.0, acc) + weights[s] * k_s
                y_j = jnp.where(s == 3, y_j + (h / 6.0) * acc, y_j)
                return y_j, acc, k_s

            return jax.lax.fori_loop(1, 4 * substeps, stage, (y, k1, k1))[0]

        def sample_interval(y, k):
            t_k = inputs.t0 + k * inputs.dt
            # One evaluation gives both the readings at sample k and the first RK4 stage.
            k1, reading = model.evaluate(t_k, y, args)
            return (unrolled if self.unroll else rolled)(t_k, y, k1), reading

        y_end, ys = jax.lax.scan(sample_interval, y0, jnp.arange(inputs.num_samples - 1))
        t_end = inputs.t0 + (inputs.num_samples - 1) * inputs.dt
        ys = jnp.concatenate([ys, model.sensors(t_end, y_end, args)[None]])
        return ys, jnp.asarray(True)


class AdaptiveTsit5(AbstractSolver):
    """Adaptive Tsit5 through `diffrax.diffeqsolve` (the reference path).

    Attributes:
        rtol, atol: step-size tolerances.
        max_steps: bound on the number of steps (failure is flagged, not raised).
    """

    rtol: float = eqx.field(static=True, default=1e-6)
    atol: float = eqx.field(static=True, default=1e-8)
    max_steps: int = eqx.field(static=True, default=100_000)

    def integrate(self, model, y0, args):
        inputs = args.inputs
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(model.vector_field),
            diffrax.Tsit5(),
            inputs.t0,
            inputs.ts[-1],
            None,
            y0,
            args=args,
            saveat=diffrax.SaveAt(ts=inputs.ts, fn=model.sensors),
            # Steps land on the samples: the linearly interpolated inputs kink there.
            stepsize_controller=diffrax.ClipStepSizeController(
                diffrax.PIDController(rtol=self.rtol, atol=self.atol), step_ts=inputs.ts
            ),
            max_steps=self.max_steps,
            throw=False,
        )
        return sol.ys, sol.result == diffrax.RESULTS.successful


def Solver(
    dt: float | None = 0.0025, rtol: float = 1e-6, atol: float = 1e-8, max_steps: int = 100_000
) -> AbstractSolver:
    """`RK4(dt)`, or `AdaptiveTsit5(rtol, atol, max_steps)` when `dt` is None."""
    if dt is None:
        return AdaptiveTsit5(rtol=rtol, atol=atol, max_steps=max_steps)
    return RK4(dt=dt)
