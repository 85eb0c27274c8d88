"""The driving that informs the lateral dynamics is used, in the car's own terms; straights are not."""

from types import SimpleNamespace

import numpy as np
import pytest

from vdsbi.io import build_recording, find_segments
from vdsbi.io._segments import min_window
from vdsbi.problem import ProblemSettings, make_problem
from vdsbi.problem._windows import lateral_information_share
from vdsbi.simulator import CHANNELS, Inputs, default_vehicle, simulate, theta_from_dict

#: A stiff, slightly understeering car: at 30 m/s a quarter of the seed profile's 0.05 rad of
#: road-wheel angle makes about 3 m/s² of lateral acceleration.
RACE_THETA = theta_from_dict(
    {"l_f": 1.3, "h_cog": 0.45, "C_kappa_f": 1.5e5, "C_kappa_r": 1.5e5, "C_alpha_f": 9e4, "C_alpha_r": 1.1e5}
)
SPEED = 30.0
DT = 0.005


def _smooth_steps(t: np.ndarray, times: list[float], levels: list[float], ramp: float = 1.0) -> np.ndarray:
    """Piecewise-constant `levels` switching at `times`, each switch a cosine ramp of `ramp` s."""
    out = np.full_like(t, levels[0])
    for t_k, (a, b) in zip(times, zip(levels, levels[1:])):
        s = np.clip((t - t_k) / ramp, 0.0, 1.0)
        out += (b - a) * 0.5 * (1 - np.cos(np.pi * s))
    return out


def _recording(steer: np.ndarray, seed: int = 0):
    """A speed-driven drive at SPEED with gyro and accelerometer noise (no torque columns)."""
    t = DT * np.arange(steer.size)
    speed = np.full_like(t, SPEED)
    inputs = Inputs(0.0, DT, steer, 0 * t, 0 * t, speed=speed, accel=0 * t)
    ys, ok = simulate(RACE_THETA, inputs, default_vehicle(), longitudinal="speed")
    assert ok
    rng = np.random.default_rng(seed)
    noise = {"ay": 0.1, "yaw_rate": 0.003, "ax": 0.1}
    cols = {"t": t, "steer": steer, "vx": speed}
    for c, s in noise.items():
        cols[c] = np.asarray(ys[:, CHANNELS.index(c)]) + s * rng.standard_normal(t.size)
    return build_recording(cols, "race.csv")


def _ay(rec, a: float, b: float) -> np.ndarray:
    return rec.channels["ay"][(rec.t >= a) & (rec.t <= b)]


def test_steady_cornering_with_little_steer_is_used_in_full_and_a_straight_is_dropped():
    # 0–12 s straight at constant speed; 12–60 s left and right corners of 5–8 s at ±0.0135 rad
    # (about ±3 m/s²) joined by 1 s transitions: over most 2 s windows the steer moves by far
    # less than a passenger car's threshold of 0.005 rad std.
    t = DT * np.arange(int(60.0 / DT))
    d = 0.0135
    times = [12.0, 19.0, 26.0, 34.0, 39.0, 46.0, 53.0]
    steer = _smooth_steps(t, times, [0.0, d, -d, d, -0.8 * d, d, -d, 0.7 * d])
    rec = _recording(steer)
    cornering = np.abs(_ay(rec, 14.0, 60.0))
    assert 2.0 < np.median(cornering) and np.quantile(cornering, 0.9) < 4.5
    assert np.abs(steer[t > 13.0]).max() <= 0.25 * 0.05 * 1.1  # a quarter of the seed's steer

    prob = make_problem(rec, default_vehicle(), ProblemSettings(longitudinal="speed", max_window=10.0))
    spans = sorted((w.t0, w.t1) for w in prob.windows)
    # Every second of the cornering is inside a window, and the windows are contiguous from a
    # lead-in on the straight (the burn-in falls there) to the end of the drive.
    assert spans[0][0] == pytest.approx(prob.description["seconds"]["dropped"], abs=0.05)
    assert 10.5 <= spans[0][0] <= 12.0 and spans[-1][1] == pytest.approx(rec.t[-1])
    assert all(b0 == pytest.approx(a1) for (_, a1), (b0, _) in zip(spans, spans[1:]))
    # The straight is dropped with the figure that decided.
    stretches = prob.description["stretches"]
    assert stretches[0][0] == 0.0 and stretches[0][2].startswith("dropped: straight: |v·r| rms 0.0")
    assert all(s[2].startswith("kept: cornering") for s in stretches[1:])
    seconds = prob.summary()["seconds"]
    assert seconds["dropped"] == pytest.approx(11.0, abs=0.6) and seconds["drive"] == pytest.approx(
        60.0, abs=0.01
    )
    summary = prob.summary()
    assert summary["train_seconds"] + summary["held_out_seconds"] > 40.0
    # The dropped straight carries no lateral information; the windows carry nearly all of it.
    assert 0.97 < summary["lateral_information_share"] <= 1.0


def test_a_short_corner_is_its_own_window_and_a_blip_is_too_short():
    # Straights with one 2.5 s corner at 3 m/s² (old rule: "too short (< 5 s)") and a 0.3 s
    # flick too quick for the 0.5 s lateral level to reach the threshold.
    t = DT * np.arange(int(40.0 / DT))
    d = 0.0135
    steer = _smooth_steps(t, [10.0, 12.0], [0.0, d, 0.0], ramp=0.5)
    steer += 0.0005 * np.exp(-(((t - 30.0) / 0.1) ** 2))
    rec = _recording(steer)
    prob = make_problem(rec, default_vehicle(), ProblemSettings(longitudinal="speed", max_window=10.0))
    assert len(prob.windows) == 1
    w = prob.windows[0]
    # The corner is whole inside the window, with a lead-in of one burn-in before it.
    assert 8.9 <= w.t0 <= 10.3 and 12.4 <= w.t1 <= 14.0
    assert w.duration >= min_window(SPEED, 1.0) - 1e-9
    assert prob.train.any() and prob.held.any()
    kept = [s for s in prob.description["stretches"] if s[2].startswith("kept")]
    assert len(kept) == 1 and "lead-in" in kept[0][2]


def test_minimum_window_follows_the_lateral_time_constant():
    # Burn-in plus five side-slip time constants v / (9.5 g), at least one fitted second.
    assert min_window(10.0, 1.0) == pytest.approx(2.0)
    assert min_window(40.0, 1.0) == pytest.approx(1.0 + 5 * 40.0 / (np.sqrt(90.0) * 9.81))
    assert min_window(40.0, 0.5) < min_window(40.0, 1.0)


def test_a_noisy_lateral_channel_raises_the_bar_above_the_floor():
    # A gentle 0.6 m/s² corner passes the 0.005 g floor on a clean gyro and not on one whose
    # noise, 0.15 rad/s at 200 Hz, puts three stds of the 0.5 s mean of |v·r| at 1.35 m/s².
    t = DT * np.arange(int(30.0 / DT))
    steer = _smooth_steps(t, [10.0, 20.0], [0.0, 0.0028, 0.0])
    clean = _recording(steer)
    noisy_cols = {"t": clean.t, "steer": clean.steer, **clean.channels}
    rng = np.random.default_rng(1)
    noisy_cols["yaw_rate"] = noisy_cols["yaw_rate"] + 0.15 * rng.standard_normal(clean.t.size)
    noisy = build_recording(noisy_cols, "noisy.csv")
    assert any(s.usable for s in find_segments(clean))
    assert not any(s.usable for s in find_segments(noisy))


def test_lateral_information_share_counts_the_squared_lateral_activity_inside_the_pieces():
    t = np.arange(0.0, 10.0, 0.01)
    rec = SimpleNamespace(t=t)
    activity = np.where(t < 5.0, 1.0, 3.0)  # 5 s at 1 m/s², 5 s at 3 m/s²: energies 1 : 9
    assert lateral_information_share(rec, [(5.0, 10.0)], activity) == pytest.approx(0.9, abs=0.01)
    assert lateral_information_share(rec, [(0.0, 10.0)], activity) == pytest.approx(1.0)
    assert lateral_information_share(rec, [], activity) == 0.0
    assert lateral_information_share(rec, [(0.0, 10.0)], np.zeros_like(t)) is None
    assert lateral_information_share(rec, [(0.0, 10.0)], None) is None
