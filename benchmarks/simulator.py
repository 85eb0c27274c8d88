"""Simulator throughput: draws per second of the batched JAX simulator against scipy and numpy.

Measures, in one run, at the seed's maneuver (5 s at 200 Hz, default float32 RK4 at 2.5 ms):

* JAX `solve_batch` for N = 1, 100, 1000, 5000 draws after compilation (best of a few calls),
  with its compile time and CPU time (the machine is shared: CPU time shows the work done
  when the wall clock is inflated by other processes);
* (a) `scipy.integrate.solve_ivp` (RK45, rtol 1e-6, atol 1e-8) looping over draws with a numpy
  port of the same right-hand side: measured on a few draws and extrapolated per draw;
* (b) a numpy RK4 vectorised over the batch at the same 2.5 ms step and dtype;
* the sharded path on 4, 2 and 1 forced host devices, in subprocesses (the main run uses the
  devices of the calling environment: one CPU device per core unless ``VDSBI_CPU_DEVICES=N``, see
  ``vdsbi/simulator/_sharding.py``);
* the cost of the step size that the wheel dynamics need (2.5 ms vs 5 ms).

Writes benchmarks/results/simulator.json and the table as simulator.md beside it. `--quick` runs
a tiny version (used by the test suite), writing to --out (default: no file).

    .venv/bin/python benchmarks/simulator.py            # full, ~3–5 min on a quiet 2-core box
    .venv/bin/python benchmarks/simulator.py --quick
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "simulator.json"
V0 = 10.5


# ----------------------------------------------------------------------------- numpy port


def numpy_rhs(t, y, theta, veh, inputs):
    """The base model's vector field and sensor readings (seed eq. 1–13), in numpy.

    A line-by-line port of `vdsbi.simulator.models.VehicleModel`'s `evaluate` without effects.

    Args:
        t: time, s.
        y: (9, N) states.
        theta: (6, N) parameters.
        veh: vdsbi Vehicle.
        inputs: (t0, dt, U) with U (3, T) the sampled steer, torque_front, torque_rear.

    Returns:
        dy (9, N) and readings (6, N).
    """
    dtype = y.dtype.type
    m, L, mu = dtype(veh.mass), dtype(veh.wheelbase), dtype(veh.friction)
    g, c_vert, r_free = dtype(9.81), dtype(veh.tire_vertical_stiffness), dtype(veh.wheel_radius)
    vx, vy, r, wf, wr, a_f_hat, a_r_hat, k_f_hat, k_r_hat = y
    t0, dt, U = inputs
    s = min(max((t - t0) / dt, 0.0), U.shape[1] - 1.0)
    i = min(max(int(np.floor(s)), 0), U.shape[1] - 2)
    w = dtype(s - i)
    delta, torque_f, torque_r = U[:, i] * (1 - w) + U[:, i + 1] * w
    l_f, h, ckf, ckr, caf, car = theta
    l_r = L - l_f
    i_z = m * l_f * l_r
    fz_f0, fz_r0 = m * g * l_r / L, m * g * l_f / L
    cos_d, sin_d = np.cos(delta), np.sin(delta)

    def demand(ck, ca, kappa, alpha):
        one_k = np.maximum(1 + kappa, dtype(0.05))
        tan_a = np.tan(alpha)
        d2 = (ck * kappa) ** 2 + (ca * tan_a) ** 2
        pos = d2 > 1e-12
        dem = np.sqrt(np.where(pos, d2, 1))
        inv = np.where(pos, one_k / (2 * dem), dtype(1e6))
        return ck * kappa / one_k, ca * tan_a / one_k, inv

    def with_load(d, fz):
        fx_lin, fy_lin, inv = d
        lam = mu * np.maximum(fz, 0) * inv
        f = np.where(lam < 1, (2 - lam) * lam, 1)
        return fx_lin * f, fy_lin * f

    dem_f = demand(ckf, caf, k_f_hat, a_f_hat)
    dem_r = demand(ckr, car, k_r_hat, a_r_hat)
    a_x = np.zeros_like(vx)
    for _ in range(3):  # LOAD_ITERATIONS
        fz_f = fz_f0 - m * h * a_x / L
        fz_r = fz_r0 + m * h * a_x / L
        fx_f, fy_f = with_load(dem_f, fz_f)
        fx_r, fy_r = with_load(dem_r, fz_r)
        a_x = (fx_f * cos_d - fy_f * sin_d + fx_r) / m
    a_y = (fx_f * sin_d + fy_f * cos_d + fy_r) / m
    vx_pos = np.maximum(vx, dtype(0.5))
    alpha_f = delta - np.arctan((vy + l_f * r) / vx_pos)
    alpha_r = -np.arctan((vy - l_r * r) / vx_pos)
    r_eff_f = r_free - fz_f / (3 * c_vert)
    r_eff_r = r_free - fz_r / (3 * c_vert)
    rw_f, rw_r = r_eff_f * wf, r_eff_r * wr
    kappa_f = (rw_f - vx) / np.maximum(np.maximum(rw_f, vx), dtype(0.5))
    kappa_r = (rw_r - vx) / np.maximum(np.maximum(rw_r, vx), dtype(0.5))
    rate = np.maximum(vx, 0) / dtype(veh.relaxation_length)
    dwf = (torque_f - fx_f * r_eff_f) / dtype(veh.wheel_inertia)
    dwr = (torque_r - fx_r * r_eff_r) / dtype(veh.wheel_inertia)
    dy = np.stack(
        [
            a_x + vy * r,
            a_y - vx * r,
            (l_f * (fx_f * sin_d + fy_f * cos_d) - l_r * fy_r) / i_z,
            dwf,
            dwr,
            rate * (alpha_f - a_f_hat),
            rate * (alpha_r - a_r_hat),
            rate * (kappa_f - k_f_hat),
            rate * (kappa_r - k_r_hat),
        ]
    )
    return dy, np.stack([a_x, a_y, r, wf, wr, vx])


def numpy_initial_state(theta, veh, v0):
    dtype = theta.dtype.type
    L, m = dtype(veh.wheelbase), dtype(veh.mass)
    fz_f0, fz_r0 = m * dtype(9.81) * (L - theta[0]) / L, m * dtype(9.81) * theta[0] / L
    r_eff = lambda fz: dtype(veh.wheel_radius) - fz / (3 * dtype(veh.tire_vertical_stiffness))
    v0 = np.broadcast_to(np.asarray(v0, dtype), theta[0].shape)
    z = np.zeros_like(v0)
    return np.stack([v0, z, z, v0 / r_eff(fz_f0), v0 / r_eff(fz_r0), z, z, z, z])


def numpy_rk4(theta, veh, inputs, v0, substeps=2):
    """(N, T, 6) readings: RK4 vectorised over the batch, `substeps` steps per sample."""
    t0, dt, U = inputs
    y = numpy_initial_state(theta, veh, v0)
    h = dt / substeps
    f = lambda t, y: numpy_rhs(t, y, theta, veh, inputs)[0]
    out = [numpy_rhs(t0, y, theta, veh, inputs)[1]]
    for k in range(U.shape[1] - 1):
        for j in range(substeps):
            t = t0 + k * dt + j * h
            k1 = f(t, y)
            k2 = f(t + h / 2, y + (h / 2) * k1)
            k3 = f(t + h / 2, y + (h / 2) * k2)
            k4 = f(t + h, y + h * k3)
            y = y + (h / 6) * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(numpy_rhs(t0 + (k + 1) * dt, y, theta, veh, inputs)[1])
    return np.stack(out).transpose(2, 0, 1)


def scipy_one(theta, veh, inputs, v0, rtol=1e-6, atol=1e-8):
    """(T, 6) readings of one draw with scipy's adaptive RK45."""
    from scipy.integrate import solve_ivp

    t0, dt, U = inputs
    th = theta[:, None]
    ts = t0 + dt * np.arange(U.shape[1])
    fun = lambda t, y: numpy_rhs(t, y[:, None], th, veh, inputs)[0][:, 0]
    y0 = numpy_initial_state(th, veh, v0)[:, 0]
    sol = solve_ivp(fun, (ts[0], ts[-1]), y0, method="RK45", t_eval=ts, rtol=rtol, atol=atol)
    if not sol.success:
        raise RuntimeError(sol.message)
    return np.stack([numpy_rhs(t, sol.y[:, [k]], th, veh, inputs)[1][:, 0] for k, t in enumerate(ts)])


# ----------------------------------------------------------------------------- JAX side


def jax_draws_per_s(ns, duration, repeats, dt=0.0025):
    """{N: {...}} for the batched JAX simulator on the current devices."""
    import jax
    import jax.numpy as jnp

    from vdsbi.simulator import (
        PARAM_NAMES,
        SEED_TRUE_THETA,
        default_vehicle,
        make_model,
        seed_profile,
        solve_batch,
    )
    from vdsbi.simulator.solvers import Solver

    model = make_model(default_vehicle())
    inputs = seed_profile(duration)
    theta0 = np.array([SEED_TRUE_THETA[n] for n in PARAM_NAMES], dtype=np.float32)
    solver = Solver(dt=dt)
    out = {}
    for n in ns:
        rng = np.random.default_rng(n)
        theta = jnp.asarray(theta0 * rng.uniform(0.95, 1.05, (n, 6)).astype(np.float32))
        v0 = jnp.asarray(rng.uniform(10, 11, n).astype(np.float32))
        t = time.perf_counter()
        ys, ok = solve_batch(model, theta, inputs, v0, (), solver)
        ys.block_until_ready()
        first = time.perf_counter() - t
        walls, cpus = [], []
        for _ in range(repeats if n < 5000 else max(1, repeats - 1)):
            c, t = time.process_time(), time.perf_counter()
            ys, ok = solve_batch(model, theta, inputs, v0, (), solver)
            ys.block_until_ready()
            walls.append(time.perf_counter() - t)
            cpus.append(time.process_time() - c)
        best = min(walls)
        out[n] = {
            "seconds": best,
            "draws_per_s": n / best,
            "cpu_seconds": min(cpus),
            "compile_s": max(first - best, 0.0),
            "all_ok": bool(ok.all()),
            "devices": jax.device_count(),
        }
        print(
            f"  jax N={n:5d}: {best:8.3f} s  {n / best:10.1f} draws/s  (cpu {min(cpus):.2f} s, "
            f"compile {first - best:.1f} s, {jax.device_count()} device(s))",
            flush=True,
        )
    return out


def jax_in_subprocess(devices, ns, duration, repeats):
    env = dict(os.environ)
    env["XLA_FLAGS"] = (
        env.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={devices}"
    ).strip()
    env["JAX_PLATFORMS"] = "cpu"
    cmd = [sys.executable, __file__, "--jax-only", "--duration", str(duration), "--repeats", str(repeats)]
    cmd += ["--ns", *map(str, ns)]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-2000:])
    print(proc.stdout.rstrip().rsplit("\n", 1)[0], flush=True)
    return {int(k): v for k, v in json.loads(proc.stdout.strip().splitlines()[-1]).items()}


# ----------------------------------------------------------------------------- main


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="tiny sizes, for the test suite")
    ap.add_argument(
        "--out", help="JSON to write (default: benchmarks/results/simulator.json; none with --quick)"
    )
    ap.add_argument("--jax-only", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--ns", type=int, nargs="*", help=argparse.SUPPRESS)
    ap.add_argument("--duration", type=float, default=5.0, help=argparse.SUPPRESS)
    ap.add_argument("--repeats", type=int, default=3, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    if args.jax_only:
        res = jax_draws_per_s(args.ns, args.duration, args.repeats)
        print(json.dumps(res))
        return res

    quick = args.quick
    duration = 0.5 if quick else 5.0
    ns = [4] if quick else [1, 100, 1000, 5000]
    n_numpy = 4 if quick else 1000
    n_scipy = 1 if quick else 3
    repeats = 1 if quick else 3
    load_start = os.getloadavg()
    print(
        f"simulator benchmark: seed maneuver {duration:g} s at 200 Hz, float32 RK4 at 2.5 ms; "
        f"load {load_start[0]:.2f} on {os.cpu_count()} cores",
        flush=True,
    )

    import jax

    from vdsbi.simulator import (
        PARAM_NAMES,
        SEED_TRUE_THETA,
        default_vehicle,
        make_model,
        seed_profile,
        solve_batch,
    )

    jax_res = jax_draws_per_s(ns, duration, repeats)
    n_big = ns[-1]

    # The cost of the step the wheel dynamics need: 5 ms (one RK4 step per sample) is stable
    # but misses the float32 accuracy target on ax; the default is 2.5 ms.
    step_res = None if quick else jax_draws_per_s([n_big], duration, max(1, repeats - 1), dt=0.005)[n_big]

    veh = default_vehicle()
    prof = seed_profile(duration)
    U = np.stack([np.asarray(prof.steer), np.asarray(prof.torque_front), np.asarray(prof.torque_rear)])
    theta0 = np.array([SEED_TRUE_THETA[n] for n in PARAM_NAMES])

    # (b) numpy RK4 vectorised over the batch, same step and dtype (float32).
    rng = np.random.default_rng(0)
    th_np = (theta0[:, None] * rng.uniform(0.95, 1.05, (6, n_numpy))).astype(np.float32)
    inputs32 = (0.0, prof.dt, U.astype(np.float32))
    c, t = time.process_time(), time.perf_counter()
    ys_np = numpy_rk4(th_np, veh, inputs32, np.float32(V0))
    numpy_s = time.perf_counter() - t
    numpy_cpu = time.process_time() - c
    print(
        f"  numpy RK4 N={n_numpy}: {numpy_s:.2f} s ({n_numpy / numpy_s:.1f} draws/s, cpu {numpy_cpu:.2f} s)",
        flush=True,
    )
    # faithfulness of the port: numpy float32 vs JAX float32, same draws
    ys_jax = np.asarray(solve_batch(make_model(veh), th_np.T[:4].copy(), prof, np.full(4, V0, np.float32))[0])
    port_diff = float((np.abs(ys_np[:4] - ys_jax).max((0, 1)) / np.abs(ys_jax).max((0, 1))).max())

    # (a) scipy solve_ivp, one draw at a time, extrapolated per draw.
    scipy_times = []
    for k in range(n_scipy):
        t = time.perf_counter()
        ys_sp = scipy_one(th_np[:, k].astype(np.float64), veh, (0.0, prof.dt, U.astype(np.float64)), V0)
        scipy_times.append(time.perf_counter() - t)
    scipy_per_draw = float(np.mean(scipy_times))
    scipy_diff = float(
        (np.abs(ys_sp - ys_jax[n_scipy - 1]).max(0) / np.abs(ys_jax[n_scipy - 1]).max(0)).max()
    )
    print(f"  scipy solve_ivp RK45: {scipy_per_draw:.2f} s per draw (mean of {n_scipy})", flush=True)

    sharded = {}
    if not quick:
        for devices in (4, 2, 1):
            sharded[devices] = jax_in_subprocess(devices, [1000, 5000], duration, 2)

    jax_per_draw_big = jax_res[n_big]["seconds"] / n_big
    n_cmp = n_numpy if n_numpy in jax_res else n_big
    load_end = os.getloadavg()
    result = {
        "config": {
            "maneuver": f"seed profile, {duration:g} s at 200 Hz ({int(duration * 200) + 1} samples)",
            "solver": "RK4, fixed 2.5 ms (2 steps per sample), float32, lax.scan",
            "quick": quick,
            "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores (shared)",
            "jax": jax.__version__,
            "devices": jax.device_count(),
            "device": f"{jax.devices()[0].platform}:{jax.devices()[0].device_kind}",
            "default_devices_note": "the main figures use the calling environment's devices "
            "(one CPU device per core unless VDSBI_CPU_DEVICES=N)",
        },
        "loadavg_start": list(load_start),
        "loadavg_end": list(load_end),
        "draws_per_s": {str(n): r["draws_per_s"] for n, r in jax_res.items()},
        "seconds": {str(n): r["seconds"] for n, r in jax_res.items()},
        "cpu_seconds": {str(n): r["cpu_seconds"] for n, r in jax_res.items()},
        "seconds_5000": jax_res[5000]["seconds"] if 5000 in jax_res else None,
        "cpu_seconds_5000": jax_res[5000]["cpu_seconds"] if 5000 in jax_res else None,
        "compile_s": jax_res[n_big]["compile_s"],
        "compile_s_by_n": {str(n): r["compile_s"] for n, r in jax_res.items()},
        "all_ok": all(r["all_ok"] for r in jax_res.values()),
        "scipy": {
            "method": "solve_ivp RK45, rtol 1e-6, atol 1e-8, float64, numpy port of the same RHS",
            "draws_measured": n_scipy,
            "seconds_per_draw": scipy_per_draw,
            "note": f"measured on {n_scipy} draw(s), extrapolated linearly per draw",
            "max_rel_diff_vs_jax": scipy_diff,
        },
        "numpy_rk4": {
            "method": "RK4 at 2.5 ms vectorised over the batch, float32, numpy port of the same RHS",
            "n": n_numpy,
            "seconds": numpy_s,
            "cpu_seconds": numpy_cpu,
            "draws_per_s": n_numpy / numpy_s,
            "max_rel_diff_vs_jax": port_diff,
        },
        "speedup_vs_scipy": scipy_per_draw / jax_per_draw_big,
        "speedup_vs_scipy_note": f"scipy s/draw over JAX s/draw at N={n_big}",
        "speedup_vs_numpy_rk4": (numpy_s / n_numpy) / (jax_res[n_cmp]["seconds"] / n_cmp),
        "speedup_vs_numpy_rk4_note": f"same N={n_cmp}, wall clock",
        "speedup_vs_numpy_rk4_cpu": (numpy_cpu / n_numpy) / (jax_res[n_cmp]["cpu_seconds"] / n_cmp),
        "sharded": {
            f"{d}_devices": {
                str(n): {
                    "seconds": r["seconds"],
                    "draws_per_s": r["draws_per_s"],
                    "cpu_seconds": r["cpu_seconds"],
                }
                for n, r in res.items()
            }
            for d, res in sharded.items()
        },
        "wheel_stiffness": {
            "handling": "explicit RK4 at a fixed 2.5 ms step, no implicit solver: the wheel/slip-relaxation "
            "oscillator has |lambda| ~ 170-270 rad/s, |lambda|·h <= 0.7 at 2.5 ms (RK4's stability limit is "
            "2.8), so 5 ms is stable too; 2.5 ms is chosen for accuracy (float32 ax error at torque steps "
            "below a tenth of the sensor noise), not for stability",
            "draws_per_s_at_5ms": step_res and step_res["draws_per_s"],
            "cpu_seconds_at_5ms": step_res and step_res["cpu_seconds"],
            "cost_factor_2_5ms_vs_5ms": step_res and step_res["draws_per_s"] / jax_res[n_big]["draws_per_s"],
            "cost_factor_2_5ms_vs_5ms_cpu": step_res
            and jax_res[n_big]["cpu_seconds"] / step_res["cpu_seconds"],
            "n": n_big,
        },
        "targets": {
            "seconds_5000_le_1": None if 5000 not in jax_res else jax_res[5000]["seconds"] <= 1.0,
            "speedup_vs_scipy_ge_200": scipy_per_draw / jax_per_draw_big >= 200,
            "speedup_vs_numpy_rk4_ge_2": (numpy_s / n_numpy) / (jax_res[n_cmp]["seconds"] / n_cmp) >= 2,
        },
    }
    _print_table(result)
    out = args.out or (None if quick else str(RESULTS))
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps(result, indent=2) + "\n")
        Path(out).with_suffix(".md").write_text(markdown(result))
        print(f"wrote {out} and its .md")
    return result


def _print_table(r):
    print()
    print(f"{'what':44s} {'N':>6s} {'seconds':>9s} {'draws/s':>10s}")
    for n, d in r["draws_per_s"].items():
        label = f"JAX solve_batch (default: {r['config']['devices']} device(s))"
        print(f"{label:44s} {n:>6s} {r['seconds'][n]:9.3f} {d:10.1f}")
    for dev, res in r["sharded"].items():
        for n, x in res.items():
            print(
                f"{'JAX solve_batch sharded, ' + dev.replace('_', ' '):44s} {n:>6s} {x['seconds']:9.3f} "
                f"{x['draws_per_s']:10.1f}"
            )
    nr = r["numpy_rk4"]
    print(f"{'numpy RK4 vectorised':44s} {nr['n']:>6d} {nr['seconds']:9.3f} {nr['draws_per_s']:10.1f}")
    sp = r["scipy"]
    print(
        f"{'scipy solve_ivp loop (per draw, extrapolated)':44s} {1:>6d} {sp['seconds_per_draw']:9.3f} "
        f"{1 / sp['seconds_per_draw']:10.2f}"
    )
    print()
    print(
        f"speedup vs scipy {r['speedup_vs_scipy']:.0f}x, vs numpy RK4 {r['speedup_vs_numpy_rk4']:.1f}x "
        f"(cpu {r['speedup_vs_numpy_rk4_cpu']:.1f}x); compile {r['compile_s']:.1f} s; "
        f"2.5 ms step costs {r['wheel_stiffness']['cost_factor_2_5ms_vs_5ms_cpu'] or float('nan'):.2f}x the "
        "CPU of 5 ms; "
        f"load {r['loadavg_start'][0]:.1f} -> {r['loadavg_end'][0]:.1f}"
    )
    print("targets:", r["targets"])


def markdown(r) -> str:
    """The result ``r`` as a Markdown table: wall seconds per batch of N draws, and the baselines."""
    c = r["config"]
    rows = [(f"JAX, default ({c['devices']} device(s))", r["seconds"])]
    rows += [
        (f"JAX, {d.replace('_', ' ')}", {n: x["seconds"] for n, x in res.items()})
        for d, res in r["sharded"].items()
    ]
    ns = list(r["seconds"])
    lines = [
        f"# Simulator throughput ({c['maneuver']}; {c['solver']})",
        "",
        f"{c['machine']}, JAX {c['jax']}, {c['device']}; load {r['loadavg_start'][0]:.1f} -> {r['loadavg_end'][0]:.1f}.",
        "",
        "| wall s, draws N | " + " | ".join(ns) + " |",
        "|---" * (len(ns) + 1) + "|",
        *[
            "| " + name + " | " + " | ".join(f"{s[n]:.3f}" if n in s else "" for n in ns) + " |"
            for name, s in rows
        ],
        "",
        f"Compile {r['compile_s']:.1f} s. Speed-up against scipy solve_ivp per draw: {r['speedup_vs_scipy']:.0f}x; "
        f"against a numpy RK4 vectorised over N = {r['numpy_rk4']['n']}: {r['speedup_vs_numpy_rk4']:.1f}x wall, "
        f"{r['speedup_vs_numpy_rk4_cpu']:.1f}x CPU.",
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
