"""The baseline a vehicle engineer would write: a linear single-track model, least squares.

Independent of vdsbi's simulator on purpose (numpy + scipy only), so it is a real comparison:
states side speed v_y and yaw rate r, driven by the measured speed v_x(t) and road-wheel angle
δ(t); linear tyres F_yf = C_f·α_f, F_yr = C_r·α_r with α_f = δ − (v_y + a·r)/v_x,
α_r = −(v_y − b·r)/v_x; m(v̇_y + v_x·r) = F_yf + F_yr, I_z·ṙ = a·F_yf − b·F_yr, and
a_y = (F_yf + F_yr)/m. Each window starts from the measured yaw rate with the steady-state side
speed; C_f and C_r are fitted by `scipy.optimize.least_squares` on yaw rate and lateral
acceleration, each scaled by its measured std.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.optimize import least_squares


@dataclasses.dataclass(frozen=True)
class Car:
    mass: float
    a: float  # CoG to front axle, m
    b: float  # CoG to rear axle, m
    iz: float  # yaw inertia, kg·m²


def simulate(car: Car, cf: float, cr: float, t, vx, delta, r0):
    """(yaw rate, a_y) over one window by RK4 at the sample interval (inputs held linear)."""
    dt = float(t[1] - t[0])
    v = np.maximum(vx, 1.0)
    alpha_r0 = car.mass * v[0] * r0 * car.a / ((car.a + car.b) * cr)
    y = np.array([car.b * r0 - v[0] * alpha_r0, r0])

    def forces(y, vxk, dk):
        fyf = cf * (dk - (y[0] + car.a * y[1]) / vxk)
        fyr = cr * (-(y[0] - car.b * y[1]) / vxk)
        return fyf, fyr

    def rhs(y, vxk, dk):
        fyf, fyr = forces(y, vxk, dk)
        return np.array([(fyf + fyr) / car.mass - vxk * y[1], (car.a * fyf - car.b * fyr) / car.iz])

    out_r, out_ay = np.empty(len(t)), np.empty(len(t))
    for k in range(len(t)):
        fyf, fyr = forces(y, v[k], delta[k])
        out_r[k], out_ay[k] = y[1], (fyf + fyr) / car.mass
        if k + 1 == len(t):
            break
        vm, dm = 0.5 * (v[k] + v[k + 1]), 0.5 * (delta[k] + delta[k + 1])
        k1 = rhs(y, v[k], delta[k])
        k2 = rhs(y + 0.5 * dt * k1, vm, dm)
        k3 = rhs(y + 0.5 * dt * k2, vm, dm)
        k4 = rhs(y + dt * k3, v[k + 1], delta[k + 1])
        y = y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return out_r, out_ay


def fit(car: Car, windows, x0=(80e3, 120e3)) -> tuple[float, float]:
    """Least-squares C_f, C_r over windows [(t, vx, delta, r_meas, ay_meas), …]."""
    r_all = np.concatenate([w[3] for w in windows])
    ay_all = np.concatenate([w[4] for w in windows])
    sr, sa = np.std(r_all), np.std(ay_all)

    def residual(logc):
        cf, cr = np.exp(logc)
        res = []
        for t, vx, delta, r, ay in windows:
            pr, pa = simulate(car, cf, cr, t, vx, delta, r[0])
            res += [(pr - r) / sr, (pa - ay) / sa]
        return np.concatenate(res)

    sol = least_squares(residual, np.log(np.asarray(x0, float)), x_scale=1.0, diff_step=1e-3)
    cf, cr = np.exp(sol.x)
    return float(cf), float(cr)
