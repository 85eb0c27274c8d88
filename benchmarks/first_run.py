"""The first run: the README's first command (set up, then the demo) in a fresh clone, timed.

Clones the repository's HEAD into a temporary folder and runs the README's first command there
in its two parts, each timed: the set-up (a virtual environment and the pinned install) and
`vdsbi demo`, with ``VDSBI_COMPILATION_CACHE`` pointing at an empty folder, so that every
program is compiled as on a new machine. Reads from the demo's output what it named and the
refined estimate. The target is 4 minutes for both parts on a 2-core CPU.

Writes benchmarks/results/first_run.json and first_run.md beside it.

    .venv/bin/python benchmarks/first_run.py      # ~4–6 min
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results" / "first_run.json"
TARGET_S = 240.0
DEMO = ".venv/bin/vdsbi demo"


def readme_command(readme: Path = ROOT / "README.md") -> tuple[str, str]:
    """The README's first command split into (set-up, demo): the first line of its code blocks
    that runs `vdsbi demo`."""
    for line in readme.read_text().splitlines():
        if line.rstrip().endswith(DEMO):
            setup, _, _ = line.rpartition(" && ")
            return setup, DEMO
    raise ValueError(f"{readme}: no line ending in {DEMO!r}")


def _timed(command: str, cwd: Path, env: dict) -> tuple[float, str]:
    t = time.perf_counter()
    proc = subprocess.run(["bash", "-c", command], cwd=cwd, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - t
    if proc.returncode != 0:
        sys.exit(f"first_run: {command!r} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    return seconds, proc.stdout


def _refined(out: str, cwd: Path) -> dict:
    """What the demo named and the refined estimate, from its printed output and folder."""
    folder = Path(re.search(r"results in (\S+);", out).group(1))
    named = re.search(r"effects named: ([^(]+) \(", out).group(1).strip()
    runs = sorted((cwd / folder).glob("identify-*/posterior.json"))
    estimate = {}
    if runs:
        params = json.loads(runs[0].read_text())["parameters"]
        estimate = {k: float(v["estimate"]) for k, v in params.items()}
    clock = float(re.search(r"demo finished in ([0-9.]+) s", out).group(1))
    return {"named": named, "refined_estimate": estimate, "demo_clock_s": clock}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(RESULTS), help="JSON to write (Markdown beside it)")
    args = ap.parse_args(argv)
    setup, demo = readme_command()
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        clone, cache = Path(tmp) / "clone", Path(tmp) / "cache"
        cache.mkdir()
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        drop = ("XLA_FLAGS", "JAX_COMPILATION_CACHE_DIR", "VIRTUAL_ENV", "PYTHONPATH")
        env = {k: v for k, v in os.environ.items() if k not in drop} | {"VDSBI_COMPILATION_CACHE": str(cache)}
        print(f"first run in a fresh clone: {setup}", flush=True)
        setup_s, _ = _timed(setup, clone, env)
        print(f"  set-up {setup_s:.0f} s; then {demo}", flush=True)
        demo_s, out = _timed(demo, clone, env)
        found = _refined(out, clone)
    total = setup_s + demo_s
    res = {
        "commit": commit.strip(),
        "command": f"{setup} && {demo}",
        "setup_s": round(setup_s, 1),
        "demo_s": round(demo_s, 1),
        "total_s": round(total, 1),
        "target_s": TARGET_S,
        "met": total <= TARGET_S,
        **found,
        "machine": {
            "cpus": os.cpu_count(),
            "load_at_start": round(load, 2),
            "python": platform.python_version(),
        },
    }
    out_json = Path(args.out)
    out_json.parent.mkdir(parents=True, exist_ok=True)
    out_json.write_text(json.dumps(res, indent=2) + "\n")
    out_json.with_suffix(".md").write_text(markdown(res))
    print(markdown(res))
    return res


def markdown(res: dict) -> str:
    verdict = "met" if res["met"] else "missed"
    rows = "\n".join(f"| {k} | {v:.4g} |" for k, v in res["refined_estimate"].items())
    return f"""# The first run

`{res["command"]}` in a fresh clone of {res["commit"][:10]}, with an empty compilation cache,
on {res["machine"]["cpus"]} CPUs (load {res["machine"]["load_at_start"]} at the start).

| part | seconds |
|---|---|
| set-up (virtual environment, pinned install) | {res["setup_s"]:.0f} |
| `vdsbi demo` (the demo's own clock: {res["demo_clock_s"]:.0f} s) | {res["demo_s"]:.0f} |
| **total** (target ≤ {res["target_s"]:.0f} s: {verdict}) | **{res["total_s"]:.0f}** |

The demo named **{res["named"]}**; the refined estimate:

| parameter | estimate |
|---|---|
{rows}
"""


if __name__ == "__main__":
    main()
