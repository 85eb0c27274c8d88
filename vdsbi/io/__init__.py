"""Readers and validation for user recordings (CSV, Parquet, ROS2 bags) and vehicle files."""

from ._bag import (
    AUTOWARE_MSGS as AUTOWARE_MSGS,
    DEFAULT_TOPIC_MAP as DEFAULT_TOPIC_MAP,
    TopicField as TopicField,
    autoware_typestore as autoware_typestore,
    load_topic_map as load_topic_map,
    read_bag as read_bag,
)
from ._bag_writer import write_bag as write_bag
from ._consistency import kinematic_slopes as kinematic_slopes, steer_response as steer_response
from ._contract import LIMITS as LIMITS, build_recording as build_recording
from ._csv import read_csv as read_csv
from ._drive import (
    check_against_vehicle as check_against_vehicle,
    load_drive as load_drive,
    read_recording as read_recording,
)
from ._errors import InputError as InputError, SimulationError as SimulationError
from ._files import (
    CHECKPOINT as CHECKPOINT,
    checkpoint_dir as checkpoint_dir,
    output_dir as output_dir,
    write_atomically as write_atomically,
    write_text_atomically as write_text_atomically,
)
from ._parquet import read_parquet as read_parquet
from ._recording import Recording as Recording, speed_slope as speed_slope
from ._resample import noise_gain as noise_gain, running_mean as running_mean
from ._segments import (
    Segment as Segment,
    estimate_noise_std as estimate_noise_std,
    find_segments as find_segments,
    label_runs as label_runs,
    lateral_level as lateral_level,
    lateral_time_constant as lateral_time_constant,
    min_window as min_window,
    usable_segments as usable_segments,
)
from ._speed import (
    SpeedEstimate as SpeedEstimate,
    estimate_speed as estimate_speed,
    forward_speed as forward_speed,
)
from ._vehicle_file import read_vehicle as read_vehicle
