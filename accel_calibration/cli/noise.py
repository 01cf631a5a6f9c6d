"""accel-calib noise: accelerometer and gyroscope noise figures from the still stretch of a recording
(any format open_recording reads), by overlapping Allan deviation (core/allan.py): a plain table, the
Kalibr fields (--kalibr imu.yaml) and a log-log figure (--plot)."""
from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..bag.recording import FORMATS
from ..core.errors import CalibrationError
from ..core.units import AXES

if TYPE_CHECKING:  # imported where used: the Allan fit needs scipy, which `accel-calib --help` does not pay for
    from ..bag.recording import Recording
    from ..core.allan import Figure, NoiseFit
    from ..core.band_noise import OperatingNoise
from ..io.output_paths import check_output_places, check_outputs, write_bytes_atomically

MIN_STILL_S = 20.0  # tau up to ~2 s with 9 clusters: the white-noise density at tau = 1 s, and no more
UNITS = {"accelerometer": "m/s^2", "gyroscope": "rad/s"}
DENSITY_UNITS = {"accelerometer": "m/s^2/sqrt(Hz)", "gyroscope": "rad/s/sqrt(Hz)"}
WALK_UNITS = {"accelerometer": "m/s^3/sqrt(Hz)", "gyroscope": "rad/s^2/sqrt(Hz)"}


def add_parser(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    parser = commands.add_parser(
        "noise", help="noise density, random walk and bias instability from a still recording (Allan deviation)",
        description="Overlapping Allan deviation per axis of the longest still stretch of the recording, fitted "
                    "whole (quantization, white noise, bias instability, random walk, rate ramp): white noise "
                    "density (sigma at tau = 1 s of its -1/2 line), random walk (sigma at tau = 3 s of its +1/2 "
                    "line) and bias instability (its flat floor / 0.664), each with its 95 % interval, or its "
                    "95 % upper bound when the recording does not resolve it.")
    parser.add_argument("recording", metavar="RECORDING",
                        help="a rosbag2 directory, a .mcap or .db3 file, a PX4 .ulg log, an ArduPilot .bin log, "
                             "or a CSV of raw samples")
    parser.add_argument("--format", choices=FORMATS, default=None)
    parser.add_argument("--imu-topic", default=None, help="bags: sensor_msgs/Imu topic (default: the only one)")
    parser.add_argument("--instance", type=int, default=None, metavar="N",
                        help="ULog: sensor_accel instance N; DataFlash: IMU instance N")
    parser.add_argument("--time-unit", choices=("s", "ms", "us", "ns"), default=None, help="CSV: time column unit")
    parser.add_argument("--units", choices=("mps2", "g", "counts"), default=None, help="CSV: units of ax,ay,az")
    parser.add_argument("--counts-per-g", type=float, default=None, metavar="COUNTS", help="CSV with --units counts")
    parser.add_argument("--whole", action="store_true",
                        help="use the whole recording (known to be still) instead of the longest still stretch "
                             "the detector finds")
    parser.add_argument("--kalibr", default=None, metavar="IMU.yaml", help="write Kalibr's imu.yaml")
    parser.add_argument("--rostopic", default="/imu0", help="--kalibr: the IMU topic (default /imu0)")
    parser.add_argument("--plot", default=None, metavar="FIG.png", help="write the log-log figure")
    parser.add_argument("--operating", action="store_true",
                        help="also the noise in operation: the longest stretch beside the still one (the vehicle "
                             "running), its density over 5 Hz..0.4 x the rate (the vehicle's motion, below, left out) "
                             "beside the static figure, and their ratio")
    parser.add_argument("--noise", choices=("static", "operating"), default="static",
                        help="--kalibr: the white-noise densities to write, the still stretch's (default) or those "
                             "in operation (with --operating)")
    return parser


MERGE_GAP_S = 0.5  # the detector cuts a long still interval into poses a sample or a window apart
MERGE_ANGLE_DEG = 1.0


def still_stretch(t_ns: np.ndarray, accel: np.ndarray, gyro: np.ndarray | None) -> tuple[int, int]:
    """[first, last) sample indices of the longest still stretch: the calibration session's still intervals
    (poses), joined where one follows the other within MERGE_GAP_S in the same orientation (the detector
    hands a long stillness over as consecutive poses of about a minute)."""
    from ..core.session import CalibrationSession

    session = CalibrationSession()
    poses = sorted(session.add_recording(t_ns, accel, gyro if gyro is not None else np.zeros_like(accel)),
                   key=lambda pose: pose.start_ns)
    if not poses:
        raise CalibrationError("no still stretch found: hold the sensor still (or give --whole if it was)")
    stretches: list[list[int]] = []
    previous = None
    for pose in poses:
        joined = (previous is not None and pose.start_ns - previous.end_ns <= MERGE_GAP_S * 1e9
                  and float(np.dot(pose.direction, previous.direction)) >= np.cos(np.radians(MERGE_ANGLE_DEG)))
        if joined:
            stretches[-1][1] = pose.end_ns
        else:
            stretches.append([pose.start_ns, pose.end_ns])
        previous = pose
    start_ns, end_ns = max(stretches, key=lambda stretch: stretch[1] - stretch[0])
    first = int(np.searchsorted(t_ns, start_ns, side="left"))
    last = int(np.searchsorted(t_ns, end_ns, side="right"))
    return first, last


DROPOUT_PERIODS = 2.5  # a step longer than this many sample periods lost samples ...
GAP_PERIODS = 20.0  # ... and one longer than this breaks the stream (shorter ones: a few samples dropped)
MAX_DROPOUT_SHARE = 1e-3  # dropped-sample steps tolerated per sample (an autopilot's log drops a few)


def unbroken_stretch(t_ns: np.ndarray) -> tuple[int, int, float, int]:
    """([first, last) of the longest stretch without a gap, its rate from the sample period (the median
    step), the number of gaps): Allan deviation assumes one sample per period, and a rate from samples /
    span would take a gap's length for slower sampling. A few dropped samples (steps of up to GAP_PERIODS)
    are borne; more than MAX_DROPOUT_SHARE of them are refused."""
    steps = np.diff(t_ns.astype(np.int64))
    if len(steps) < 2 or np.any(steps <= 0):
        raise CalibrationError("stamps must increase: Allan deviation needs samples in time order")
    period_ns = float(np.median(steps))
    # np.greater, not `>`: numpy's stubs type np.diff of int64 stamps as timedelta64, which `>` a float refuses
    breaks = np.flatnonzero(np.greater(steps, GAP_PERIODS * period_ns)) + 1
    edges = np.concatenate([[0], breaks, [len(t_ns)]])
    longest = int(np.argmax(np.diff(edges)))
    first, last = int(edges[longest]), int(edges[longest + 1])
    dropouts = int(np.count_nonzero(np.greater(steps[first:last - 1], DROPOUT_PERIODS * period_ns)))
    if dropouts > max(1, int(MAX_DROPOUT_SHARE * (last - first))):
        raise CalibrationError(f"{dropouts} steps of more than {DROPOUT_PERIODS:g} sample periods in "
                               f"{last - first} samples: Allan deviation needs an unbroken stream")
    return first, last, 1e9 / period_ns, len(breaks)


def _figure_text(figure: Figure, scale: float = 1.0, absent: str = "not present") -> str:
    """The figure with its 95 % interval, or its 95 % upper bound when the curve does not resolve it."""
    bounded = 0.0 < figure.high < math.inf
    if not figure.present and not bounded:
        return absent
    if not figure.resolved:
        if not bounded:
            return absent
        needs = "" if figure.needs_s is None else ": needs " + (
            f"{figure.needs_s / 3600:.1f} h" if figure.needs_s >= 3600 else f"{figure.needs_s / 60:.0f} min") + " still"
        return f"< {figure.high * scale:.3g} (not resolved{needs})"
    return f"{figure.value * scale:.3g} [{figure.low * scale:.3g}, {figure.high * scale:.3g}]"


def noise_table(fits: dict[str, list[NoiseFit] | None]) -> str:
    rows = [f"{'channel':8s} {'white noise density':>34s} {'random walk':>34s} {'bias instability':>40s}"]
    for sensor, axes in fits.items():
        if axes is None:
            rows.append(f"{sensor}: no noise measurable (constant or quantized)")
            continue
        rows.append(f"{sensor}: density {DENSITY_UNITS[sensor]}, random walk {WALK_UNITS[sensor]}, "
                    f"bias instability {UNITS[sensor]} (95 % intervals)")
        for axis, fit in zip(AXES, axes):
            n = fit.noise
            bias = _figure_text(n.bias_instability, absent="not present (no flat floor)")
            if n.bias_instability.resolved:
                bias += f" at {n.bias_instability.at_tau_s:.3g} s"
            white = _figure_text(n.white_density, absent="not resolved (no -1/2 slope)")
            rows.append(f"  {sensor[0]}{axis:6s} {white:>34s} "
                        f"{_figure_text(n.random_walk):>34s} {bias:>40s}")
    return "\n".join(rows)


def run(args: argparse.Namespace) -> int:
    from ..bag.recording import open_recording
    from ..core.allan import required_duration_s

    if args.noise == "operating" and not args.operating:
        raise CalibrationError("--noise operating needs --operating (the noise in operation is measured with it)")
    outputs = [("--kalibr", args.kalibr), ("--plot", args.plot)]
    check_outputs(outputs, [args.recording])
    check_output_places(outputs)
    recording = open_recording(args.recording, args.format, imu_topic=args.imu_topic, instance=args.instance,
                               time_unit=args.time_unit, units=args.units, counts_per_g=args.counts_per_g)
    t_ns = recording.t_ns
    if len(t_ns) < 3:
        raise CalibrationError(f"{args.recording}: {len(t_ns)} samples: too few for noise figures")
    first, last = (0, len(t_ns)) if args.whole else still_stretch(t_ns, recording.accel_mps2, recording.gyro_radps)
    within, beyond, rate, gaps = unbroken_stretch(t_ns[first:last])
    if gaps:
        whole = float(t_ns[last - 1] - t_ns[first]) * 1e-9
        first, last = first + within, first + beyond
        print(f"{gaps} gap(s) of more than {GAP_PERIODS:g} sample periods in the {whole:.1f} s taken: the longest "
              "unbroken stretch is used")
    t = t_ns[first:last]
    duration_s = float(t[-1] - t[0]) * 1e-9 if len(t) > 1 else 0.0
    if duration_s < MIN_STILL_S:
        raise CalibrationError(
            f"{args.recording}: the still stretch lasts {duration_s:.1f} s: the noise density needs at least "
            f"{MIN_STILL_S:g} s still, the random walk within +-25 % about {required_duration_s(800.0) / 3600:.0f} h")
    channels = {"accelerometer": recording.accel_mps2[first:last]}
    if recording.gyro_radps is not None:
        channels["gyroscope"] = recording.gyro_radps[first:last]
    fits = {sensor: channel_fits(values, rate, duration_s) for sensor, values in channels.items()}
    print(f"{args.recording}: {recording.stream}, still {t_ns[first] * 1e-9:.1f}..{t_ns[last - 1] * 1e-9:.1f} s "
          f"({duration_s / 60:.1f} min, {len(t)} samples at {rate:.1f} Hz)")
    print(noise_table(fits))
    operating = _operating(args, recording, (first, last), rate, fits) if args.operating else None
    if args.kalibr:
        _write_kalibr(args, fits, rate, duration_s, operating)
    if args.plot:
        from ..io.noise_figure import write_noise_figure

        with tempfile.TemporaryDirectory(prefix="accel-calib-noise-") as scratch:
            rendered = Path(scratch) / "noise.png"
            measured = {sensor: axes for sensor, axes in fits.items() if axes is not None}
            write_noise_figure(measured, UNITS, rendered, title=Path(args.recording).name)
            write_bytes_atomically(args.plot, rendered.read_bytes())
        print(f"figure {args.plot}")
    return 0


def channel_fits(values: np.ndarray, rate_hz: float, duration_s: float) -> list[NoiseFit] | None:
    """The three axes' figures of one sensor, or None when an axis has no noise to measure (its Allan
    deviation is 0 at some tau: constant or coarsely quantized samples, a gyro of all zeros)."""
    from ..core.allan import fit_noise, overlapping_adev

    tau, adev, relative = overlapping_adev(values, rate_hz)
    if not np.all(adev > 0):
        return None
    return [fit_noise(tau, adev[:, axis], relative, duration_s, tau0_s=1.0 / rate_hz) for axis in range(3)]


MIN_RUNNING_S = 5.0  # the band average over 5 Hz..0.4 x the rate needs ~4 s (band_noise.MIN_SEGMENTS)


def _operating(args: argparse.Namespace, recording: Recording, still: tuple[int, int], rate: float,
               fits: dict[str, list[NoiseFit] | None]) -> dict[str, OperatingNoise]:
    """The noise in operation per sensor (core/band_noise.py) from the longest stretch before or after the
    still one, printed beside the static figures with their ratio."""
    from ..core.band_noise import operating_noise

    t_ns = recording.t_ns
    start, stop = max((0, still[0]), (still[1], len(t_ns)), key=lambda span: span[1] - span[0])
    if args.whole or stop - start < 3:
        raise CalibrationError(f"{args.recording}: --operating needs the vehicle running beside a still stretch; "
                               "there is none (without --whole, the still stretch is the detector's)")
    within, beyond, running_rate, _ = unbroken_stretch(t_ns[start:stop])
    start, stop = start + within, start + beyond
    seconds = float(t_ns[stop - 1] - t_ns[start]) * 1e-9
    if seconds < MIN_RUNNING_S or abs(running_rate / rate - 1.0) > 0.01:
        raise CalibrationError(f"{args.recording}: the running stretch lasts {seconds:.1f} s at {running_rate:.1f} Hz: "
                               f"--operating needs {MIN_RUNNING_S:g} s at the still stretch's rate ({rate:.1f} Hz)")
    sources = {"accelerometer": recording.accel_mps2, "gyroscope": recording.gyro_radps}
    found: dict[str, OperatingNoise] = {}
    for sensor, axes in fits.items():
        values = sources[sensor]
        if axes is None or values is None:
            continue
        static = np.array([f.noise.white_density.value for f in axes])
        found[sensor] = operating_noise(values[still[0]:still[1]], values[start:stop], rate, static)
    low, high = next(iter(found.values())).band_hz if found else (0.0, 0.0)
    print(f"in operation {t_ns[start] * 1e-9:.1f}..{t_ns[stop - 1] * 1e-9:.1f} s ({seconds / 60:.1f} min): "
          f"density over {low:g}..{high:g} Hz (the vehicle's motion, below, left out), as the static density "
          "scaled by the band's ratio running / still")
    for sensor, noise in found.items():
        for axis, fit, running, ratio in zip(AXES, fits[sensor] or [], noise.operating_density, noise.ratio):
            print(f"  {sensor[0]}{axis:6s} static {fit.noise.white_density.value:.3g}  operating {running:.3g} "
                  f"{DENSITY_UNITS[sensor]}  ratio {ratio:.2f}")
    return found


def _write_kalibr(args: argparse.Namespace, fits: dict[str, list[NoiseFit] | None], rate: float,
                  duration_s: float, operating: dict[str, OperatingNoise] | None = None) -> None:
    """Kalibr's imu.yaml from the figures, or one line saying which figure is missing (never a 0)."""
    from ..io.calibration_file import write_text_atomically
    from ..io.estimator_yaml import NoiseFigures, kalibr_imu_yaml

    if "gyroscope" not in fits:
        raise CalibrationError(f"{args.recording}: no gyroscope in the recording: Kalibr's imu.yaml needs its "
                               "figures too")
    silent = [sensor for sensor, axes in fits.items() if axes is None]
    if silent:
        raise CalibrationError(f"{args.recording}: no noise measurable in the {' and '.join(silent)} (constant or "
                               "quantized samples): no figures for Kalibr's imu.yaml")
    measured = {sensor: axes for sensor, axes in fits.items() if axes is not None}
    absent = [f"{sensor} {axis}" for sensor, axes in measured.items() for axis, f in zip(AXES, axes)
              if not f.noise.white_density.present]
    if absent:
        raise CalibrationError(f"{args.recording}: no white-noise region (-1/2 slope) in the Allan curve of "
                               f"{', '.join(absent)}: no noise density for Kalibr; record longer or faster")
    densities = {sensor: max(f.noise.white_density.value for f in axes) for sensor, axes in measured.items()}
    which = "static: the still stretch's white noise"
    if args.noise == "operating" and operating is not None:
        densities = {sensor: float(np.max(noise.operating_density)) for sensor, noise in operating.items()}
        low, high = next(iter(operating.values())).band_hz
        which = (f"in operation: the static density x the ratio of the running to the still stretch's density over "
                 f"{low:g}..{high:g} Hz")
    figures = NoiseFigures(  # the largest axis of each: Kalibr takes one figure per sensor
        accelerometer_noise_density=densities["accelerometer"],
        accelerometer_random_walk=max(f.noise.random_walk.value for f in measured["accelerometer"]),
        gyroscope_noise_density=densities["gyroscope"],
        gyroscope_random_walk=max(f.noise.random_walk.value for f in measured["gyroscope"]),
        update_rate_hz=rate)
    comment = (f"accel-calib noise {Path(args.recording).name}: the largest axis of each figure; "
               f"{duration_s / 60:.1f} min still at {rate:.1f} Hz\nnoise densities {which}")
    unresolved = [s for s, axes in measured.items() if not all(f.noise.random_walk.resolved for f in axes)]
    said = ""
    if unresolved:  # the bound holds 95 % of the time: an estimator trusting the bias too long is the harm
        said = (f"random walk of the {' and '.join(unresolved)} not resolved: *_random_walk is its 95 % upper bound, "
                "not an estimate (record longer still to resolve it)")
        comment += "\n" + said
    write_text_atomically(args.kalibr, kalibr_imu_yaml(figures, args.rostopic, comment))
    print(f"written {args.kalibr}" + (f" ({said})" if said else ""))
