"""The fleet's pieces on known cases: Pareto-smoothed importance sampling's k̂, the sequential test
per car and parameter, the manifest's errors."""

import time

import numpy as np
import pytest
from drives import answer_crude, fleet_drive

from vdsbi.cli import main
from vdsbi.fleet._changes import detect_changes
from vdsbi.fleet._manifest import read_manifest
from vdsbi.fleet._psis import gpd_fit, psis


@pytest.mark.parametrize("k", [0.2, 0.5, 0.9])
def test_gpd_fit_recovers_the_shape_of_pareto_draws(k):
    rng = np.random.default_rng(0)
    x = np.sort((rng.uniform(size=20_000) ** -k - 1.0) / k)  # generalized Pareto, σ = 1
    k_hat, sigma = gpd_fit(x)
    assert abs(k_hat - k) < 0.03 and abs(sigma - 1.0) < 0.05


def test_psis_k_hat_of_a_normal_proposal_follows_the_weights_tail():
    """Target N(0, 1), proposal N(0, s²): the weights' tail index is 1/(1 − s²), so k = 1 − s²
    for s < 1 (heavy-tailed weights), and k̂ < 0 for a wider proposal (bounded weights)."""
    rng = np.random.default_rng(1)
    found = {}
    for s in (0.6, 0.9, 1.5):
        ks = []
        for _ in range(10):
            x = rng.normal(0.0, s, 2000)
            weights, k = psis(-0.5 * x**2 + 0.5 * (x / s) ** 2)
            assert np.isclose(weights.sum(), 1.0)
            ks.append(k)
        found[s] = float(np.mean(ks))
    assert abs(found[0.6] - (1 - 0.36)) < 0.15
    assert abs(found[0.9] - (1 - 0.81)) < 0.15
    assert found[1.5] < 0.0
    # the smoothed weights' estimate of E[x²] under the target
    x = rng.normal(0.0, 1.5, 4000)
    weights, _ = psis(-0.5 * x**2 + 0.5 * (x / 1.5) ** 2)
    assert abs(np.sum(weights * x**2) - 1.0) < 0.1


def test_psis_says_no_when_one_draw_has_all_the_weight():
    lw = np.full(256, -1e4)
    lw[3] = 0.0
    _, k = psis(lw)
    assert k > 0.7


def _sequence(rng, n, step_at=None, step=0.0):
    s = rng.uniform(0.5, 2.0, n)
    truth = np.where(np.arange(n) >= (step_at if step_at is not None else n), step, 0.0)
    m = rng.normal(truth, s)
    return m, m - 1.645 * s, m + 1.645 * s


def test_cusum_false_alarm_rate_and_detection():
    """In control (calibrated intervals, nothing changes): under 1 alarm in 300 drives. A step of
    6 posterior std: caught and dated at its first drive in nearly every sequence."""
    rng = np.random.default_rng(2)
    alarms = drives = 0
    for _ in range(1000):
        m, lo, hi = _sequence(rng, 20)
        alarms += len(detect_changes("c", "p", [str(i) for i in range(20)], m, lo, hi))
        drives += 19
    assert alarms / drives < 1 / 300
    hits = 0
    for _ in range(300):
        s = np.ones(8)
        m = rng.normal(np.where(np.arange(8) >= 4, 6.0, 0.0), s)
        found = detect_changes("c", "p", [str(i) for i in range(8)], m, m - 1.645 * s, m + 1.645 * s)
        hits += any(c.index == 4 and c.after > c.before for c in found)
    assert hits / 300 > 0.9


def _manifest(tmp_path, rows):
    (tmp_path / "r.csv").write_text("t,steer\n0,0\n")
    (tmp_path / "v.json").write_text("{}")
    path = tmp_path / "manifest.csv"
    path.write_text("car,recording,vehicle,time\n" + "".join(r + "\n" for r in rows))
    return path


def test_manifest_orders_drives_and_names_bad_lines(tmp_path, capsys):
    path = _manifest(tmp_path, ["b,r.csv,v.json,2025-01-02", "a,r.csv,v.json,3", "a,../x.csv,v.json,1"])
    with pytest.raises(ValueError, match=r"line 4: recording.*does not exist"):
        read_manifest(path)
    path = _manifest(tmp_path, ["b,r.csv,v.json,2025-01-02", "a,r.csv,v.json,3"])
    drives = read_manifest(path)
    assert [d.car for d in drives] == ["a", "b"] and drives[0].line == 3
    path = _manifest(tmp_path, ["a,r.csv,v.json,yesterday"])
    assert main(["fleet", str(path), "--out", str(tmp_path / "out")]) == 2
    assert "line 2: time" in capsys.readouterr().err
    path = _manifest(tmp_path, ["a,r.csv,v.json,1", "a,r.csv,v.json,2"])
    assert main(["fleet", str(path), "--out", str(tmp_path / "out")]) == 2
    assert "line 3: recording" in capsys.readouterr().err
    (tmp_path / "bad.csv").write_text("car,recording,time\na,r.csv,1\n")
    assert main(["fleet", str(tmp_path / "bad.csv"), "--out", str(tmp_path / "out")]) == 2
    assert "missing column(s) vehicle" in capsys.readouterr().err


def test_report_images_decode(tmp_path):
    """Every plot of report.html is an embedded PNG that decodes: the page loads without fetching
    anything."""
    import base64
    import io
    import re

    import matplotlib.image

    from vdsbi.fleet._changes import Change
    from vdsbi.fleet._report import write_report

    def record(car, time, method, value):
        p = {"estimate": value, "q05": value - 1, "q50": value, "q95": value + 1, "identified": True}
        return {
            "car": car,
            "recording": f"{car}/{time}.csv",
            "time": time,
            "method": method,
            "platform": "p",
            "noise_ratio": {"ay": 1.2},
            "parameters": {"l_f": p, "C_alpha_f": p},
        }

    records = [
        record("a", "1", "amortized+fit", 1.0),
        record("a", "2", "identify", 5.0),
        record("b", "1", "amortized", 2.0),
    ]
    write_report(tmp_path / "report.html", records, [Change("a", "l_f", "2", 1, 1.0, 5.0)], 12.0)
    page = (tmp_path / "report.html").read_text()
    images = re.findall(r"src='data:image/png;base64,([^']+)'", page)
    assert len(images) == 2
    for data in images:
        assert matplotlib.image.imread(io.BytesIO(base64.b64decode(data))).shape[0] > 50
    assert "l_f from 2: 1 → 5" in page


def test_cluster_by_address_sets_up_its_workers(tmp_path):
    """`--address`: the client joins an existing scheduler and its workers get the JAX setup."""
    distributed = pytest.importorskip("distributed")

    from vdsbi.fleet import Cluster
    from vdsbi.fleet._engine import open_client

    def cache_dir():
        import jax

        return jax.config.jax_compilation_cache_dir

    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, dashboard_address=None) as existing:
        with open_client(Cluster(address=existing.scheduler_address, compilation_cache=tmp_path)) as client:
            assert client.submit(cache_dir, pure=False).result() == str(tmp_path)


def test_local_workers_share_out_the_cores(monkeypatch):
    """Each local worker splits its batches of draws over its share of the cores, not all of them
    (two workers of two devices each on two cores would contend)."""
    pytest.importorskip("distributed")

    from vdsbi.fleet import Cluster
    from vdsbi.fleet._engine import _cores, open_client

    def devices():
        import jax

        import vdsbi  # noqa: F401  (sizes JAX's CPU devices when imported first)

        return jax.device_count()

    monkeypatch.delenv("VDSBI_CPU_DEVICES", raising=False)
    with open_client(Cluster(workers=2)) as client:
        counts = client.run(devices)
    assert sorted(counts.values()) == [max(1, _cores() // 2)] * 2


def test_a_local_cluster_left_without_workers_gives_up_its_drives(monkeypatch):
    """Every worker gone and none restarted: the run says so and returns the drives unanswered
    (a re-run retries them) instead of waiting for ever."""
    distributed = pytest.importorskip("distributed")

    from vdsbi.fleet import Cluster, _fleet

    monkeypatch.setattr(_fleet, "WORKER_CHECK_S", 0.2)
    monkeypatch.setattr(_fleet, "NO_WORKERS_S", 1.0)
    lines = []
    with distributed.LocalCluster(n_workers=1, processes=False, dashboard_address=None) as cluster:
        with distributed.Client(cluster) as client:
            quick = client.submit(lambda: 1, pure=False)
            assert list(_fleet._finished(client, {quick: "a"}, Cluster(), lines.append)) == [quick]
            cluster.scale(0)
            while client.scheduler_info()["workers"]:
                time.sleep(0.05)
            stuck = client.submit(lambda: 2, pure=False)
            assert list(_fleet._finished(client, {stuck: "b"}, Cluster(), lines.append)) == []
    assert "no workers" in lines[-1] and "1 drives not answered" in lines[-1]


def test_the_check_refuses_fewer_draws_than_its_probes_need():
    import jax

    from vdsbi.fleet._amortized import Proposal
    from vdsbi.fleet._check import importance_check
    from vdsbi.problem import Box

    box = Box(np.zeros(3), np.ones(3), ("a", "b", "c"))
    with pytest.raises(ValueError, match="at least 8"):
        importance_check(jax.random.key(0), None, box, (), Proposal(np.zeros(3), np.eye(3), 1), draws=7)


@pytest.mark.slow
def test_a_crude_proposal_is_answered_by_the_fit_its_check_starts(tmp_path, monkeypatch):
    """A drive's chain below `identify` from an amortized posterior far from the truth (1.5 prior
    std off, in every coordinate): its check fails, the fit starts from the check's best point with
    its noise, and a fit's Laplace posterior (the first's, or its reweighted refit's) passes the
    check; the answer's estimates lie within 4 posterior std of the truth."""
    from vdsbi.fleet import _drive
    from vdsbi.fleet._check import DRAWS, k_threshold
    from vdsbi.fleet._platform import drive_problem, make_platform

    recording, vehicle, truth = fleet_drive(tmp_path / "fleet", 20.0)
    platform = make_platform(vehicle, [drive_problem(recording, vehicle)])
    box = platform.box
    record = answer_crude(recording, vehicle, platform, truth, tmp_path, monkeypatch)
    assert record["method"] == "amortized+fit", record.get("escalated_because")
    # Each check failed but the last, a fit's: the amortized one, then a fit's, then its refit's.
    names, ks = list(record["checks"]), [c["k_hat"] for c in record["checks"].values()]
    assert names[:2] == ["amortized", "fit"] and len(names) <= 1 + _drive.FITS
    assert ks[-1] <= k_threshold(DRAWS - box.dim - 1)
    assert ks[0] is None or ks[0] > k_threshold(_drive.AMORTIZED_DRAWS - box.dim - 1)
    assert all(k is None or k > k_threshold(DRAWS - box.dim - 1) for k in ks[1:-1])
    scored = [n for n, q in record["parameters"].items() if q["identified"] and n in truth]
    assert {"l_f", "C_alpha_f", "C_alpha_r"} <= set(scored)
    for name in scored:
        q = record["parameters"][name]
        assert abs(q["mean"] - truth[name]) < 4 * q["std"], (name, q, truth[name])
    # The answer's weighted draws are kept beside it: their weighted means are the record's.
    saved = np.load(tmp_path / "out" / _drive.DRAWS_FILE)
    assert list(saved["names"]) == list(box.names) and np.isclose(saved["weights"].sum(), 1.0)
    means = saved["weights"] @ saved["theta"]
    for j, name in enumerate(box.names):
        assert np.isclose(means[j], record["parameters"][name]["mean"], rtol=1e-6), name
    assert list(saved["channels"]) == list(platform.channels) and np.all(saved["noise_scale"] > 0)


def test_a_drive_line_shows_the_k_hat_of_its_last_check():
    from vdsbi.fleet._fleet import _k_text

    checks = {"amortized": {"k_hat": 40.0}, "fit": {"k_hat": 1.3}, "fit2": {"k_hat": 0.21}}
    assert _k_text({"checks": checks}) == " (k̂ 0.21)"
    assert _k_text({"checks": {"amortized": {"k_hat": None}}}) == ""
    assert _k_text({}) == ""
