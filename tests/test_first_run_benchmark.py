"""The first-run benchmark times the README's first command, which installs what the second (the
one .ci/run runs) installs, less the test tools; and it reads the demo's output as it prints it."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import first_run  # noqa: E402


def test_the_benchmark_runs_the_readmes_first_command_and_it_sets_up_as_ci_does():
    setup, demo = first_run.readme_command(ROOT / "README.md")
    readme = (ROOT / "README.md").read_text()
    assert f"{setup} && {demo}\n" in readme
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    # The same package, the same options; the tests add their tools (the "dev" extra).
    assert setup.endswith(" -e .")
    assert ci.startswith(f"{setup[: -len(' -e .')]} -e '.[dev]' && ") and ci in readme


def test_it_reads_what_the_demo_prints(tmp_path):
    run = tmp_path / "vdsbi-demo" / "identify-sensor_bias"
    run.mkdir(parents=True)
    (run / "posterior.json").write_text('{"parameters": {"l_f": {"estimate": 1.497}}}')
    out = (
        "diagnosis: mismatch detected: True; effects named: sensor_bias (concealed: sensor_bias); "
        "verdict: …\ndemo finished in 230 s; results in vdsbi-demo; open vdsbi-demo/report.html\n"
    )
    found = first_run._refined(out, tmp_path)
    assert found == {"named": "sensor_bias", "refined_estimate": {"l_f": 1.497}, "demo_clock_s": 230.0}
