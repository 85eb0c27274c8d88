"""The demo's drive (the README's first command) is always a valid, rolling recording."""

import json

import numpy as np
import pytest

from vdsbi.api import demo_recording
from vdsbi.io import read_recording, read_vehicle


@pytest.mark.parametrize("seed", [0, 1])
def test_demo_recording_is_valid_and_keeps_rolling(tmp_path, seed):
    truth = demo_recording(tmp_path, duration=20.0, seed=seed)
    rec = read_recording(tmp_path / "recording.csv")
    read_vehicle(tmp_path / "vehicle.json")
    assert rec.duration == pytest.approx(20.0, abs=0.01)
    assert np.min(rec.channels["vx"]) > 4.0  # noisy vx; the noise-free speed stays > 5 m/s
    saved = json.loads((tmp_path / "truth.json").read_text())
    assert saved["concealed_effect"] == truth["concealed_effect"]
