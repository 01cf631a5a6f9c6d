"""The session's stream side: what turns sample parts into poses and motions (screening, temperature filter,
detector, motion recorder, their counters) and the rule that says which still interval is a pose. The feed
drives it; the session composes it with the pose side (store, fit, gates, verdict)."""
from __future__ import annotations

import numpy as np

from ..pose import Pose
from ..settings import Settings
from ..units import MG
from .detector import StaticDetector
from .detector_batch import DetectorConfig
from .motion_recorder import MotionRecorder
from .screening import Counters, SampleScreen
from .temperature_filter import TemperatureFilter

# |mean acceleration| of a still interval, in g, that can be gravity read by a plausible accelerometer in
# m/s^2 (bias under 2 m/s^2, gain 0.9..1.1 stay well inside); outside it is no pose and teaches no floor.
PLAUSIBLE_GRAVITY = (0.5, 1.5)


def detector_config(settings: Settings) -> DetectorConfig:
    """The detector's settings from the session's."""
    return DetectorConfig(
        window_s=settings.static_window_s,
        min_hold_s=settings.static_min_hold_s,
        accel_var_threshold=settings.static_accel_var_threshold or None,
        gyro_var_threshold=settings.static_gyro_var_threshold or None,
        k_sigma=settings.static_k_sigma,
        max_floor_rise=settings.static_max_floor_rise,
        accel_noise_ceiling=settings.static_max_noise_mg * MG,
        gyro_noise_ceiling=settings.static_max_gyro_noise_mradps * 1e-3,
        floor_min_magnitude=0.05 * settings.gravity,  # not a dead sensor's zeros (a stream in g is 0.1 g)
    )


class StreamSide:
    """Screening, temperature filter, detector and motion recorder of one stream, with the screening
    counters they share; `usable_pose` judges each still interval the detector ends."""

    def __init__(self, settings: Settings) -> None:
        self.gravity = settings.gravity
        self.counters = Counters()
        self.screen = SampleScreen(settings, self.counters)
        self.temperature = TemperatureFilter(timeout_s=settings.temperature_timeout_s)
        self.detector = StaticDetector(detector_config(settings))
        # The raw gyro between consecutive poses (the gyro fit's motions), fed by the same sample path.
        self.motions = MotionRecorder(max_motion_s=settings.gyro_max_motion_s,
                                      trailing_s=2.0 + 4 * settings.static_window_s, capacity=settings.max_poses,
                                      overlap_s=settings.static_window_s)
        # Means of the latest still intervals dropped as implausible for gravity (the stream side writes,
        # /calibrate reads: a tuple replaced whole): a stream in g says so instead of "0 poses".
        self.implausible_means: tuple[np.ndarray, ...] = ()

    def _rejection(self, pose: Pose | None, time_base: int) -> str | None:
        """Why a still interval is no pose: 'frozen' (it overlaps a frozen run), 'implausible' (|mean|
        is no gravity: outside 0.5..1.5 g, e.g. a dead sensor's zeros), 'none'; None when it is one."""
        if pose is None:
            return "none"
        if self.screen.overlaps_frozen(pose.start_ns, pose.end_ns, time_base):
            return "frozen"
        low, high = PLAUSIBLE_GRAVITY
        if not low * self.gravity <= float(np.linalg.norm(pose.accel_mps2)) <= high * self.gravity:
            return "implausible"
        return None

    def usable_pose(self, pose: Pose | None, time_base: int | None = None) -> Pose | None:
        """The pose when it is one (no frozen run overlaps it on the clock `time_base` (default: the
        screen's current one), its mean is gravity), else None, counted."""
        why = self._rejection(pose, self.screen.time_base if time_base is None else time_base)
        if why is None:
            return pose
        if why == "frozen":
            self.counters.frozen_poses_dropped += 1
        elif why == "implausible" and pose is not None:
            self.counters.implausible_poses += 1
            self.implausible_means = (*self.implausible_means[-15:], pose.accel_mps2)
        return None
