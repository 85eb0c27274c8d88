"""Every file in tests/data/bad/ fails `vdsbi check` with one line naming file and field, exit 2."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from vdsbi.cli import main, output_dir
from vdsbi.io import InputError, read_recording
from vdsbi.io._bag_writer import write_bag

DATA = Path(__file__).parent / "data"
BAD, GOOD = DATA / "bad", DATA / "good"
MANIFEST = json.loads((BAD / "manifest.json").read_text())


@pytest.fixture(scope="module")
def good_bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("bag") / "good_bag"
    write_bag(read_recording(GOOD / "recording.csv", rate=50.0), path)
    return path


def _argv(name: str, role: str, bag: Path) -> list[str]:
    vehicle = str(GOOD / "vehicle.json")
    if role == "recording":
        return [str(BAD / name), "--vehicle", vehicle]
    if role == "vehicle":
        return [str(GOOD / "recording.csv"), "--vehicle", str(BAD / name)]
    assert role == "topic_map"
    return [str(bag), "--vehicle", vehicle, "--topic-map", str(BAD / name)]


def test_manifest_covers_every_bad_file():
    files = {p.name for p in BAD.iterdir()} - {"manifest.json"}
    assert files == set(MANIFEST)
    assert len(files) >= 25


@pytest.mark.parametrize("name", sorted(MANIFEST))
def test_bad_input(name, tmp_path, capsys, good_bag):
    entry = MANIFEST[name]
    out = tmp_path / "out"
    status = main(["check", *_argv(name, entry["role"], good_bag), "--out", str(out)])
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert status == 2, captured.out
    assert len(lines) == 1, captured.err
    line = lines[0]
    assert line.startswith("vdsbi: error: ")
    assert name in line
    if entry["role"] == "topic_map":  # the bag is the file, the map is named in the message
        assert f": {entry['field']}: " in line
    else:
        assert f"{name}: {entry['field']}: " in line
    assert entry.get("contains", "") in line
    assert list(tmp_path.iterdir()) == []  # no DIR, no partial sibling


def test_good_input_passes_and_writes_dir(tmp_path, capsys):
    out = tmp_path / "out"
    status = main(
        ["check", str(GOOD / "recording.csv"), "--vehicle", str(GOOD / "vehicle.yaml"), "--out", str(out)]
    )
    captured = capsys.readouterr()
    assert status == 0, captured.err
    assert "channels   ax, ay, yaw_rate, omega_front, omega_rear, vx" in captured.out
    assert "kinematics d(vx)/dt = 1.00 × ax" in captured.out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    again = read_recording(out / "recording.csv")
    assert again.channel_names == ("ax", "ay", "yaw_rate", "omega_front", "omega_rear", "vx")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["samples"] == again.num_samples
    # the fixture's yaw rate is 0.1·sin 2t at 10 ± 1 m/s with steer 0.03·sin 2t: 9/v ≈ 0.9 of
    # v·δ/L, in step with the steer
    k = summary["kinematics"]
    assert k["yaw_rate~v*steer/L"] == pytest.approx(0.9, abs=0.06) and k["steer_lag_s"] == 0.0


def test_subprocess_exit_status_and_no_traceback(tmp_path):
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "vdsbi.cli", "check", str(BAD / "steer_in_degrees.csv")]
        + ["--vehicle", str(GOOD / "vehicle.json"), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().count("\n") == 0
    assert "steer_in_degrees.csv: steer: " in proc.stderr
    assert not out.exists()


def test_unexpected_errors_keep_their_traceback(monkeypatch):
    import vdsbi.cli._check as check

    def boom(args):
        raise RuntimeError("bug")

    monkeypatch.setattr(check, "run", boom)
    with pytest.raises(RuntimeError, match="bug"):
        main(["check", "x.csv", "--vehicle", "v.json"])


def test_output_dir_is_all_or_nothing(tmp_path):
    target = tmp_path / "sub" / "run"
    with pytest.raises(RuntimeError):
        with output_dir(target) as d:
            (d / "half.json").write_text("{}")
            raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []  # even the created parent is gone
    with output_dir(target) as d:
        assert d != target
        (d / "result.json").write_text("{}")
    assert sorted(p.name for p in target.parent.iterdir()) == ["run"]
    assert (target / "result.json").exists()
    with pytest.raises(InputError, match="not empty"):
        with output_dir(target):
            pass
    with output_dir(target, resume=True) as d:  # resume works in place
        assert d == target
        (d / "more.json").write_text("{}")
    assert sorted(p.name for p in target.iterdir()) == ["more.json", "result.json"]
