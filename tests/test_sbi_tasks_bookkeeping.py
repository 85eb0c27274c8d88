"""The sbibm grid's bookkeeping: cells resume, pieces merge, the table and the file's metadata say
what was run where. Synthetic cells, no training."""

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def grid():
    spec = importlib.util.spec_from_file_location("sbi_tasks", ROOT / "benchmarks" / "sbi_tasks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def cell(grid, method, obs_scores, device="cpu:cpu", budget=10_000, **overrides):
    """A finished cell as `run_cell` returns it, with C2ST ``obs_scores[i]`` at observation i."""
    config = grid.flat_config(grid.config_for(budget, method, **overrides))
    ids = sorted(obs_scores)
    recs = [{"obs_id": i, "c2st": obs_scores[i], "train_s": 1.0, "rounds": [], "invalid": 0} for i in ids]
    run = {"obs_ids": ids, "commit": "abc", "device": device, "loadavg": [0.1], "loadavg_end": [0.2]}
    if method not in grid.SEQUENTIAL:
        run.update(train_s=2.0, rounds=[], invalid=0)
    base = {"task": "two_moons", "method": method, "budget": budget, "config": config}
    return grid.summarise({**base, "per_observation": recs, "runs": [run]})


def test_sequential_pieces_join_and_the_newer_observation_wins(grid):
    merged = grid.merge(cell(grid, "apt", {1: 0.6, 2: 0.7}), cell(grid, "apt", {2: 0.5, 3: 0.5}))
    assert merged["obs_ids"] == [1, 2, 3]
    assert merged["c2st"] == [0.6, 0.5, 0.5]
    assert merged["c2st_mean"] == pytest.approx(1.6 / 3)
    assert len(merged["runs"]) == 2


def test_amortised_cells_and_changed_settings_replace_whole(grid):
    npe = grid.merge(cell(grid, "npe", {1: 0.6, 2: 0.7}), cell(grid, "npe", {3: 0.5}))
    assert npe["obs_ids"] == [3]
    other = grid.merge(cell(grid, "apt", {1: 0.6}), cell(grid, "apt", {2: 0.5}, patience=5))
    assert other["obs_ids"] == [2]


def test_resume_runs_only_what_is_missing(grid):
    stored_apt, stored_npe = cell(grid, "apt", {1: 0.6, 3: 0.6}), cell(grid, "npe", {1: 0.6, 2: 0.6})
    apt_config = grid.flat_config(grid.config_for(10_000, "apt"))
    npe_config = grid.flat_config(grid.config_for(10_000, "npe"))
    assert grid.todo(stored_apt, "apt", apt_config, [1, 2, 3, 4]) == [2, 4]
    assert grid.todo(stored_npe, "npe", npe_config, [1, 2]) == []
    assert grid.todo(stored_npe, "npe", npe_config, [1, 2, 3]) == [1, 2, 3]  # one network: rerun
    changed = grid.flat_config(grid.config_for(10_000, "apt", patience=5))
    assert grid.todo(stored_apt, "apt", changed, [1, 2]) == [1, 2]


def test_a_field_added_later_matches_only_at_its_default(grid):
    config = grid.flat_config(grid.config_for(10_000, "apt"))
    older = {k: v for k, v in config.items() if k != "average_epochs"}  # before the field existed
    default = grid.flat_config(grid.NPEConfig())
    assert grid.same_config(older, {**config, "average_epochs": default["average_epochs"]})
    assert not grid.same_config(older, {**config, "average_epochs": default["average_epochs"] + 1.0})


def test_a_removed_field_matches_only_at_the_value_that_made_it_a_no_op(grid):
    config = grid.flat_config(grid.config_for(10_000, "apt"))
    assert grid.same_config({**config, "ensemble": 1, "combined_loss": False}, config)
    assert not grid.same_config({**config, "ensemble": 3}, config)
    assert grid.make_config(**config) == grid.config_for(10_000, "apt")


def test_table_marks_published_comparison_and_stale_settings(grid):
    text = grid.table([cell(grid, "npe", {1: 0.55, 2: 0.57}), cell(grid, "apt", {1: 0.60}, patience=3)])
    npe_row = next(line for line in text.splitlines() if line.startswith("| two_moons | npe |"))
    apt_row = next(line for line in text.splitlines() if line.startswith("| two_moons | apt |"))
    assert "0.560±0.014 n=2 (sbibm 0.606) ✓ [2s]" in npe_row and "†" not in npe_row
    assert "(sbibm 0.554) ✗ †" in apt_row  # 0.60 above the published figure, other patience
    assert "† run with other settings" in text


def test_saved_file_names_the_cells_devices_not_the_writers(grid, tmp_path):
    out = str(tmp_path / "grid.json")
    grid._save(out, cell(grid, "npe", {1: 0.6}, device="gpu:H100"), "sbibm")
    grid._save(out, cell(grid, "apt", {1: 0.6}, device="cpu:cpu"), "sbibm")
    saved = json.loads(Path(out).read_text())
    assert saved["meta"]["device"] == "cpu:cpu, gpu:H100"
    assert saved["observations"] == "sbibm"
    assert [r["method"] for r in saved["results"]] == ["npe", "apt"]
    assert (tmp_path / "grid.md").exists()
    assert (tmp_path / "grid.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"  # the figure beside it
    assert not list(tmp_path.glob("*.tmp*"))  # written whole, then renamed


def test_a_cell_joined_across_devices_keeps_each_devices_training_time(grid):
    cpu = cell(grid, "apt", {1: 0.6, 2: 0.6})
    gpu = cell(grid, "apt", {3: 0.6}, device="gpu:H100")
    gpu["per_observation"][0]["train_s"] = 4.0
    merged = grid.merge(cpu, grid.summarise(gpu))
    assert merged["train_s_by_device"] == {"cpu:cpu": 1.0, "gpu:H100": 4.0}
    assert merged["train_s"] == pytest.approx(2.0)
    row = next(line for line in grid.table([merged]).splitlines() if line.startswith("| two_moons | apt |"))
    assert "[1s cpu, 4s gpu]" in row
    assert "[1s]" in grid.table([cpu])  # one device: one figure, as before
