"""Readers and validation for user recordings (CSV, Parquet, ROS2 bags) and vehicle files."""

from ._consistency import kinematic_slopes as kinematic_slopes, steer_response as steer_response
from ._contract import build_recording as build_recording
from ._drive import load_drive as load_drive, read_recording as read_recording
from ._errors import InputError as InputError, SimulationError as SimulationError
from ._files import (
    CHECKPOINT as CHECKPOINT,
    checkpoint_dir as checkpoint_dir,
    output_dir as output_dir,
    write_atomically as write_atomically,
    write_text_atomically as write_text_atomically,
)
from ._recording import Recording as Recording
from ._resample import noise_gain as noise_gain, running_mean as running_mean
from ._segments import (
    Segment as Segment,
    SegmentRules as SegmentRules,
    estimate_noise_std as estimate_noise_std,
    find_segments as find_segments,
    label_runs as label_runs,
)
from ._speed import estimate_speed as estimate_speed, forward_speed as forward_speed
from ._vehicle_file import read_vehicle as read_vehicle
