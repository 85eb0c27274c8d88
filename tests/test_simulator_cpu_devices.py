"""vdsbi asks JAX for CPU devices at import (one per core unless VDSBI_CPU_DEVICES says
otherwise), only when nobody chose and JAX has not started. Each case runs in a fresh interpreter."""

import os
import subprocess
import sys

import pytest

SCRIPT = "import jax\n{before}\nimport vdsbi.simulator\nprint(jax.device_count())"


def _devices(before="", **env):
    base = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "VDSBI_CPU_DEVICES")}
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT.format(before=before)],
        env={**base, "JAX_PLATFORMS": "cpu", **env},
        capture_output=True,
        text=True,
        timeout=120,
    )
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-1500:])
    return int(proc.stdout.split()[-1])


def test_default_and_auto_are_one_device_per_core():
    per_core = max(1, min(len(os.sched_getaffinity(0)), 8))
    assert _devices() == per_core
    assert _devices(VDSBI_CPU_DEVICES="auto") == per_core


def test_environment_variable_sizes_or_turns_it_off():
    assert _devices(VDSBI_CPU_DEVICES="1") == 1
    assert _devices(VDSBI_CPU_DEVICES="3") == 3


def test_the_users_choice_and_a_started_jax_are_left_alone():
    assert _devices(XLA_FLAGS="--xla_force_host_platform_device_count=3", VDSBI_CPU_DEVICES="2") == 3
    assert _devices(before="jax.config.update('jax_num_cpu_devices', 1)", VDSBI_CPU_DEVICES="2") == 1
    assert _devices(before="jax.numpy.zeros(1).block_until_ready()", VDSBI_CPU_DEVICES="2") == 1


def test_bad_value_is_a_clear_error():
    with pytest.raises(RuntimeError, match="VDSBI_CPU_DEVICES must be"):
        _devices(VDSBI_CPU_DEVICES="many")
