"""The per-drive path's shapes and shortcuts: drives of different lengths share one compiled fit,
and the shortcuts (the window ladder, the smaller amortized check, the fit without the parameters
the model has no use for) answer as the longer path does."""

import pytest
from drives import answer_crude, fleet_drive

from vdsbi.fleet._shape import LENGTH_FRACTIONS, WINDOW_COUNTS, fixed_shape, length_bucket, window_bucket


def test_the_window_ladder_pads_by_less_than_half_with_few_shapes():
    counts = [window_bucket(w) for w in range(1, 1001)]
    assert counts[:4] == [1, 2, 3, 4]
    assert all(w <= c < 1.5 * w for w, c in zip(range(1, 1001), counts))
    assert len(set(counts)) <= 20
    assert list(WINDOW_COUNTS) == sorted(set(WINDOW_COUNTS))


def test_a_drive_is_padded_to_the_shortest_length_that_holds_its_windows(tmp_path):
    from vdsbi.fleet._platform import WINDOW_SECONDS, drive_problem

    ((r, v, _),), _ = _drives(tmp_path, (30.0,))
    problem = drive_problem(r, v)
    longest = problem.t.shape[1] * problem.dt
    lengths = [f * WINDOW_SECONDS for f in LENGTH_FRACTIONS]
    chosen = length_bucket(problem, WINDOW_SECONDS)
    assert chosen == min(x for x in lengths if x >= longest)
    assert fixed_shape(problem, chosen).t.shape[1] * problem.dt <= chosen + 1e-9
    # a window longer than the shorter length: the next one
    assert (
        length_bucket(problem, 0.99 * longest / LENGTH_FRACTIONS[0]) == 0.99 * longest / LENGTH_FRACTIONS[0]
    )


def _drives(tmp_path, durations):
    """One simulated drive per duration (one car each), their truths, and the platform of them."""
    from vdsbi.fleet._platform import drive_problem, make_platform

    out = [fleet_drive(tmp_path / f"fleet{i}", seconds) for i, seconds in enumerate(durations)]
    platform = make_platform(out[0][1], [drive_problem(r, v) for r, v, _ in out])
    return out, platform


def _answer(drive, platform, truth, tmp_path, monkeypatch):
    return answer_crude(*drive, platform, truth, tmp_path, monkeypatch)


@pytest.mark.slow
def test_drives_of_two_lengths_share_one_fit_and_the_shortcuts_answer_as_the_longer_path(
    tmp_path, monkeypatch
):
    """A 22 s and a 30 s drive (three windows of different lengths each): the second drive's fit
    reuses the program the first compiled (the fit's Levenberg–Marquardt loop is traced once).
    Then the 30 s drive by the path without the shortcuts (the longest window length, 4 padded
    windows, a 128-draw amortized check, the fit over every parameter, the longitudinal slip
    stiffnesses' zero columns included): the same level, and each identified parameter's mean and
    90 % interval within half a posterior std of the other's."""
    import jax

    import vdsbi.estimation._likelihood as likelihood
    from vdsbi.fleet import _drive
    from vdsbi.fleet._platform import WINDOW_SECONDS, drive_problem

    drives, platform = _drives(tmp_path, (22.0, 30.0))
    problems = [drive_problem(r, v) for r, v, _ in drives]
    padded = [fixed_shape(p, length_bucket(p, WINDOW_SECONDS)) for p in problems]
    assert len({p.y.shape for p in padded}) == 1  # one padded shape, from different lengths
    assert len({p.y.shape for p in problems}) == 2
    traces = []
    inner = likelihood.levenberg_marquardt
    monkeypatch.setattr(likelihood, "levenberg_marquardt", lambda *a, **k: traces.append(1) or inner(*a, **k))
    jax.clear_caches()  # the count starts here, whatever earlier tests compiled
    seen, records = [], []
    for r, v, truth in drives:
        records.append(_answer((r, v), platform, truth, tmp_path, monkeypatch))
        assert records[-1]["method"] == "amortized+fit", records[-1].get("escalated_because")
        seen.append(len(traces))
    assert seen == [1, 1]

    (r, v, truth), fast = drives[1], records[1]
    monkeypatch.setattr(_drive, "AMORTIZED_DRAWS", 128)
    monkeypatch.setattr(_drive, "fitted_parameters", lambda p: p.box.names)
    monkeypatch.setattr(_drive, "fixed_shape", lambda p, s: fixed_shape(p, WINDOW_SECONDS, windows=4))
    slow = _answer((r, v), platform, truth, tmp_path / "slow", monkeypatch)
    assert fast["method"] == slow["method"] == "amortized+fit"
    for name, q in slow["parameters"].items():
        p = fast["parameters"][name]
        assert p["identified"] == q["identified"], name
        if not q["identified"]:
            continue
        for key in ("mean", "q05", "q95"):
            assert abs(p[key] - q[key]) < 0.5 * q["std"], (name, key, p, q)
