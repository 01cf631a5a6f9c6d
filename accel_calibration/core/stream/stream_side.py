"""The session's stream side: what turns sample parts into poses and motions (screening, temperature filter,
detector, motion recorder, their counters) and the rule that says which still interval is a pose. The feed
cuts a recording into parts and hands each to `take`; the session composes it with the pose side (store,
fit, gates, verdict)."""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ..pose import Pose
from ..settings import PARAMETERS, Settings
from ..units import MG
from .detector import DISCARD, RESTART, StaticDetector
from .detector_batch import DetectorConfig
from .motion_recorder import MotionRecorder
from .screening import Counters, SampleScreen
from .temperature_filter import TemperatureFilter

# |mean acceleration| of a still interval, in g, that can be gravity read by a plausible accelerometer in
# m/s^2 (bias under 2 m/s^2, gain 0.9..1.1 stay well inside); outside it is no pose and teaches no floor.
PLAUSIBLE_GRAVITY = (0.5, 1.5)


def detector_config(settings: Settings) -> DetectorConfig:
    """The detector's settings from the session's, by one rule: the parameter `static.NAME` is the detector's
    NAME (0 for a threshold: learned, None); the noise ceilings, in mg and mrad/s as people give them, go to
    the detector (which knows no unit) in SI."""
    detector = {f.name for f in fields(DetectorConfig)}
    named = {p.name.removeprefix("static."): getattr(settings, p.field) for p in PARAMETERS
             if p.name.startswith("static.") and p.name.removeprefix("static.") in detector}
    for threshold in ("accel_var_threshold", "gyro_var_threshold"):
        named[threshold] = named[threshold] or None
    return DetectorConfig(
        **named,
        accel_noise_ceiling=settings.static_max_noise_mg * MG,
        gyro_noise_ceiling=settings.static_max_gyro_noise_mradps * 1e-3,
        floor_min_magnitude=0.05 * settings.gravity,  # not a dead sensor's zeros (a stream in g is 0.1 g)
    )


@dataclass(frozen=True, eq=False)
class StreamPart:
    """One part of a stream, in arrival order: stamps (ns), acceleration (m/s^2) and angular rate (rad/s),
    (N, 3); `collecting` False where collection was paused (None: collecting throughout); `readings` the
    temperature readings (stamps ns, degC) of its time (None: the stream has no temperature); `final`: the
    last part (the interval open at its end ends)."""

    t_ns: np.ndarray
    accel_mps2: np.ndarray
    gyro_radps: np.ndarray
    collecting: np.ndarray | None = None
    readings: tuple[np.ndarray, np.ndarray] | None = None
    final: bool = False


class StreamSide:
    """Screening, temperature filter, detector and motion recorder of one stream, with the screening
    counters they share; `take` drives them over one part, `usable_pose` judges each still interval the
    detector ends.

    Carried between parts besides the parts' own state: whether a pause or a clock re-synchronisation came
    after the last sample the detector saw, and the clock of the detector's current segment."""

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
        self._paused_since = False  # a paused sample since the detector's last one
        self._restart_since = False  # a clock re-synchronisation since the detector's last one
        self._segment_base = self.screen.time_base  # the clock of the detector's current segment

    def take(self, part: StreamPart) -> list[tuple[Pose, int]]:
        """One part through screening, the motion recorder, the temperature filter and the detector: the
        still intervals it ended, each with the clock (screen time base) it was measured on; not yet judged
        (`usable_pose`: a frozen run found later may overlap one)."""
        t, accel, gyro = part.t_ns, part.accel_mps2, part.gyro_radps
        fresh = not self.detector.continuing
        time_base = self.screen.time_base
        keep, restart = self.screen.screen_arrays(t, accel, gyro)
        paused = np.zeros(len(t), dtype=bool) if part.collecting is None else ~part.collecting
        self.counters.samples_paused += int(np.count_nonzero(keep & paused))
        self.motions.add(t, gyro, keep, paused, restart)
        rows = np.flatnonzero(keep & ~paused)  # what the detector sees
        breaks = self._breaks(rows, paused, restart)
        temps = None
        if part.readings is not None:
            # Always an array (NaN: no temperature yet): the detector's parts keep one presence.
            rejected = self.temperature.rejected
            temps, stale = self.temperature.series(*part.readings, t[rows])
            self.counters.temperature_stale += stale
            self.counters.temperature_bad += self.temperature.rejected - rejected
        # Paused at the end: the interval then open was dropped when the pause began.
        found = self.detector.find(t[rows], accel[rows], gyro[rows], temps, breaks, flush=not self._paused_since,
                                   final=part.final)
        # Each pose on the clock it was measured on (frozen runs of other clocks do not overlap it): the
        # segment in force when the part began, then one per break (the first part: from its first row).
        bases = time_base + np.concatenate([[0], np.cumsum(restart)])[rows + 1]
        if fresh:
            firsts = np.concatenate([[0], np.flatnonzero(breaks[1:]) + 1]) if len(rows) else np.zeros(0, int)
            segment_bases = bases[firsts]
        else:
            segment_bases = np.concatenate([[self._segment_base], bases[np.flatnonzero(breaks)]])
        if len(rows):
            self._segment_base = int(bases[-1])
        for each in found:
            self.motions.pose_found(each.pose)
        return [(each.pose, int(segment_bases[each.segment])) for each in found]

    def _breaks(self, rows: np.ndarray, paused: np.ndarray, restart: np.ndarray) -> np.ndarray:
        """Before each detector row: a pause since the previous one drops the interval (DISCARD), else a
        clock jump ends it (RESTART); a pause in force at the start changes nothing (nothing is open)."""
        breaks = np.zeros(len(rows), dtype=np.int64)
        if not len(rows):
            self._paused_since = self._paused_since or bool(np.any(paused))
            self._restart_since = self._restart_since or bool(np.any(restart))
            return breaks
        previous = np.concatenate([[-1], rows[:-1]])
        paused_before = np.concatenate([[0], np.cumsum(paused)])
        jumps_before = np.concatenate([[0], np.cumsum(restart)])
        breaks[jumps_before[rows + 1] > jumps_before[previous + 1]] = RESTART
        breaks[paused_before[rows] > paused_before[previous + 1]] = DISCARD
        if self._restart_since and not breaks[0]:
            breaks[0] = RESTART
        if self._paused_since:
            breaks[0] = DISCARD
        self._paused_since = bool(np.any(paused[rows[-1] + 1:]))
        self._restart_since = bool(np.any(restart[rows[-1] + 1:]))
        return breaks

    def holding(self) -> Pose | None:
        """The still interval in progress as the pose it would end as now, None when there is none, it is
        no pose, or collection is paused since (it will be dropped)."""
        if self._paused_since:
            return None
        pose = self.detector.peek_open()
        if pose is None:
            return None
        return self.usable_pose(pose, self._segment_base)

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
