"""Where the test suite's time goes: JAX compilation against everything else, per test file.

Runs the README's test command (``pytest -n 2 -q``, or the given pytest arguments) with the
`_compile_events` plugin and sums, over the workers, each test's wall time and the seconds JAX
spent tracing, lowering and compiling (XLA's backend) inside it. The suite aims at ~10 min on the
2-core machine; this says what to cut. Tests run with the XLA flags ``tests/conftest.py`` sets
(``--xla_backend_optimization_level=0`` unless ``XLA_FLAGS`` names a level).

Writes benchmarks/results/suite_profile.json and prints a table.

    .venv/bin/python benchmarks/suite_profile.py                # the whole suite, ~15 min
    .venv/bin/python benchmarks/suite_profile.py -- tests/test_problem.py -n 0
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results" / "suite_profile.json"


def run_suite(pytest_args: list[str], folder: Path) -> tuple[int, float, str]:
    """Run pytest with the plugin; its exit code, wall seconds and last output line."""
    env = dict(os.environ, VDSBI_COMPILE_EVENTS_DIR=str(folder))
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(HERE), env.get("PYTHONPATH")]))
    cmd = [sys.executable, "-m", "pytest", "-p", "_compile_events", *pytest_args]
    start = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    lines = proc.stdout.strip().splitlines()
    return proc.returncode, time.perf_counter() - start, lines[-1] if lines else proc.stderr[-500:]


def per_file(folder: Path) -> dict[str, dict[str, float]]:
    """Each test file's summed seconds (over its tests and the workers) and compile count."""
    files: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    for path in folder.glob("*.json"):
        for test, stats in json.loads(path.read_text()).items():
            files[test.split("::")[0]].update(stats)
    return {f: dict(c) for f, c in sorted(files.items(), key=lambda kv: -kv[1]["wall"])}


def table(files: dict[str, dict[str, float]], top: int) -> str:
    total = collections.Counter()
    for stats in files.values():
        total.update(stats)
    head = "| file | test s | XLA compile s | tracing s | lowering s | compiles |\n|---|---|---|---|---|---|"
    rows = [("all", total)] + list(files.items())[:top]
    body = [
        f"| {name} | {s['wall']:.0f} | {s.get('backend_compile_duration', 0):.0f} | "
        f"{s.get('jaxpr_trace_duration', 0):.0f} | {s.get('jaxpr_to_mlir_module_duration', 0):.0f} | "
        f"{int(s.get('n_compiles', 0))} |"
        for name, s in rows
    ]
    return "\n".join([head, *body])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("pytest_args", nargs="*", default=["-n", "2", "-q"], help="after --")
    parser.add_argument("--top", type=int, default=15, help="files in the table")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        code, wall, last = run_suite(args.pytest_args, Path(tmp))
        files = per_file(Path(tmp))
        failed = sorted(line for f in Path(tmp).glob("*.failed") for line in f.read_text().splitlines())
    print(f"pytest {' '.join(args.pytest_args)}: exit {code}, {wall:.0f} s wall; {last}")
    print("".join(f"FAILED {line}\n" for line in failed), end="")
    print(table(files, args.top))
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    result = {
        "pytest_args": args.pytest_args,
        "exit_code": code,
        "wall_s": wall,
        "summary": last,
        "failed": failed,
        "commit": commit.stdout.strip(),
        "xla_flags": os.environ.get("XLA_FLAGS", "(tests/conftest.py's)"),
        "load_average": os.getloadavg(),
        "files": files,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1))
    return code


if __name__ == "__main__":
    sys.exit(main())
