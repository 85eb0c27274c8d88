"""Every `vdsbi …` command the README prints gets through the command line as written: its words
parse, its values convert (the `--prior` ranges, the `--theta` object, the effect lists), its
files load, and it reaches the library call, whose arguments are checked here. The library calls
are stood in for (what they do is tested end to end elsewhere: the loop test runs the identify
command diagnose prints, to the end)."""

from __future__ import annotations

import json
import shlex
import shutil
from pathlib import Path

import pytest

from vdsbi import api
from vdsbi.cli import main

ROOT = Path(__file__).resolve().parents[1]
GOOD = Path(__file__).parent / "data" / "good"


def readme_commands() -> list[str]:
    """The `vdsbi` command lines of the README's bash blocks, continuations joined, comments cut."""
    out, block, pending = [], False, ""
    for line in (ROOT / "README.md").read_text().splitlines():
        if line.startswith("```"):
            block = line.strip() == "```bash"
            continue
        if not block:
            continue
        line = pending + line.strip()
        if line.endswith("\\"):
            pending = line[:-1] + " "
            continue
        pending = ""
        if line.startswith("vdsbi "):
            out.append(shlex.join(shlex.split(line, comments=True)))
    return out


class _Reached(Exception):
    """The command got to the library call."""


COMMANDS = readme_commands()


def test_the_readme_prints_the_commands_of_its_workflow():
    names = {shlex.split(c)[1] for c in COMMANDS}
    assert {"check", "identify", "diagnose", "predict", "export", "sample", "simulate"} <= names
    assert any("--prior" in c for c in COMMANDS)


@pytest.mark.parametrize("command", COMMANDS)
def test_a_readme_command_reaches_the_library_call(command, tmp_path, monkeypatch):
    for name in ("rec.csv", "drive.csv", "a.csv", "b.csv", "other.csv"):
        shutil.copy(GOOD / "recording.csv", tmp_path / name)
    shutil.copy(GOOD / "vehicle.json", tmp_path / "vehicle.json")
    (tmp_path / "lab.json").write_text(json.dumps({"l_f": 1.3, "C_alpha_f": 8e4}))
    (tmp_path / "run").mkdir()
    calls = []

    def reached(name):
        def call(*args, **kwargs):
            calls.append((name, args, kwargs))
            raise _Reached(name)

        return call

    for name in ("check", "identify", "diagnose", "predict", "export", "sample", "simulate"):
        monkeypatch.setattr(api, name, reached(name))
    for name in ("observability", "design"):
        monkeypatch.setattr(api, name, reached(name))
    monkeypatch.setattr(api.outputs, "write_export", reached("export"))
    import vdsbi.fleet

    monkeypatch.setattr(vdsbi.fleet, "fleet", reached("fleet"))
    (tmp_path / "manifest.csv").write_text("car,recording,vehicle,time\na,rec.csv,vehicle.json,1\n")
    monkeypatch.chdir(tmp_path)
    argv = shlex.split(command)[1:]
    with pytest.raises(_Reached):
        main(argv)
    ((name, args, kwargs),) = calls
    assert name == argv[0]
    if name == "identify":
        assert isinstance(args[2], api.IdentifyOptions)
    if "--prior" in argv:
        priors = args[2].model.priors if name == "identify" else kwargs["priors"]
        for item in (argv[i + 1] for i, a in enumerate(argv) if a == "--prior"):
            param, rng = item.split("=")
            assert priors[param] == tuple(float(v) for v in rng.split(":"))


def readme_python() -> str:
    """The Python block of the README's "Python API" section."""
    text = (ROOT / "README.md").read_text().split("## Python API", 1)[1]
    return text.split("```python\n", 1)[1].split("```", 1)[0]


def test_the_readme_python_example_runs_with_its_typed_options(tmp_path, monkeypatch):
    seen = {}

    class _Result:
        def table(self):
            return "table"

    def identify(recording, vehicle, options, *, out_dir=None, progress=None):
        seen["identify"] = (options, out_dir, progress)
        return _Result()

    monkeypatch.setattr(api, "identify", identify)
    monkeypatch.setattr(api, "diagnose", lambda *a, **k: seen.setdefault("diagnose", a))
    monkeypatch.setattr(api, "export", lambda *a, **k: seen.setdefault("export", a) and "{}")
    exec(compile(readme_python(), "README.md", "exec"), {})
    options, out_dir, progress = seen["identify"]
    assert isinstance(options.drive, api.DriveOptions) and isinstance(options.budget, api.Budget)
    assert options.model.add_effects == ("sensor_bias",) and isinstance(progress, api.Progress)
    assert seen["diagnose"][2] == "diag/" and seen["export"] == ("run/", "json")
