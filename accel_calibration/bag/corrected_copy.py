"""A corrected copy of a replayed recording, in its own format: a bag (directory or single .mcap/.db3
file) with the IMU messages as the node would publish them (acceleration, gyro bias and covariance from
core.correction's one correction), a CSV with ax,ay,az corrected; a ULog or DataFlash log gets a CSV of
corrected samples. Written aside first and put in place by one rename, never over the recording."""
from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.calibration import Calibration
from ..core.correction import CorrectedSamples, correct_samples
from ..core.errors import CalibrationError
from .recording import BAGS, Recording, RecordingError

if TYPE_CHECKING:
    from .replay import ReplayResult


def corrected_samples(replay: ReplayResult, calibration: Calibration, t_ns: np.ndarray, accel: np.ndarray,
                      gyro: np.ndarray, covariance: np.ndarray | None = None,
                      angular_covariance: np.ndarray | None = None) -> CorrectedSamples:
    """What the node would publish for these samples of the replayed recording (core.correction's one
    correction, at the temperatures the node would have used)."""
    held = replay.temperatures
    return correct_samples(calibration, t_ns, accel, gyro, covariance, None if held is None else held.filtered(),
                           angular_covariance=angular_covariance)


def write_corrected_bag(replay: ReplayResult, calibration: Calibration, destination: str | os.PathLike[str],
                        **groups: int) -> int:
    """A copy of the replayed bag with the IMU accelerations corrected (at each sample's temperature), read
    and written a group at a time (corrected_bag.write_corrected; `groups`: its group sizes)."""
    from .bag_io import BagError
    from .corrected_bag import write_corrected

    def correct(t_ns: np.ndarray, accel: np.ndarray, gyro: np.ndarray, covariance: np.ndarray,
                angular_covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        done = corrected_samples(replay, calibration, t_ns, accel, gyro, covariance, angular_covariance)
        assert done.covariance is not None and done.angular_covariance is not None  # given them, it gives them
        return done.accel_mps2, done.gyro_radps, done.covariance, done.angular_covariance

    try:
        return write_corrected(replay.source.path, destination, replay.source.imu_topic, correct, **groups)
    except BagError as error:
        raise CalibrationError(str(error)) from None


# ------------------------------------------------------------------------------------------- writing
# A corrected copy is written aside first (stage_corrected_copy) and put in place by one rename
# (StagedCopy.commit), so that the CLI can do all its work before it writes any output; the clean-up
# only ever removes the scratch directory this process made, never the destination.
@dataclass
class StagedCopy:
    """A corrected copy written aside: commit() puts it in place, discard() drops what is left aside."""

    line: str  # what was written, for the summary
    commit_action: Callable[[], None]
    scratch: Path | None = None

    def commit(self) -> None:
        self.commit_action()
        self.discard()

    def discard(self) -> None:
        if self.scratch is not None:
            shutil.rmtree(self.scratch, ignore_errors=True)
            self.scratch = None


def write_corrected_copy(replay: ReplayResult, calibration: Calibration, destination: str | os.PathLike[str]) -> str:
    """A corrected copy of the replayed recording in its own format (a ULog: a CSV of corrected samples,
    t_ns,ax,ay,az,gx,gy,gz,temperature in SI units, temperature the filtered value the correction used).
    Returns a line saying what was written."""
    staged = stage_corrected_copy(replay, calibration, destination)
    try:
        staged.commit()
    finally:
        staged.discard()
    return staged.line


def _scratch_beside(target: Path) -> Path:
    try:
        return Path(tempfile.mkdtemp(prefix=".corrected-", dir=target.parent))
    except OSError as error:
        raise RecordingError(f"cannot write {target}: {error.strerror or error}") from None


def rename_no_replace(source: str | os.PathLike[str], target: str | os.PathLike[str], /) -> None:
    """Rename `source` to `target` only if nothing is there: atomic where the kernel has renameat2's
    RENAME_NOREPLACE (Linux), else checked just before. A loser of two concurrent writers fails here."""
    import ctypes
    import errno

    function = getattr(ctypes.CDLL(None, use_errno=True), "renameat2", None)
    if function is not None:
        at_cwd, no_replace = -100, 1
        if function(at_cwd, os.fsencode(source), at_cwd, os.fsencode(target), no_replace) == 0:
            return
        code = ctypes.get_errno()
        if code not in (errno.ENOSYS, errno.EINVAL):
            raise OSError(code, os.strerror(code), str(target))
    if os.path.lexists(target):
        raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), str(target))
    os.rename(source, target)


def stage_corrected_copy(replay: ReplayResult, calibration: Calibration, destination: str | os.PathLike[str]
                         ) -> StagedCopy:
    """The corrected copy (see write_corrected_copy) written aside, not yet in place."""
    recording = replay.source.recording
    kind = recording.format
    source = Path(replay.source.path)
    if Path(destination).resolve() == source.resolve():
        raise RecordingError(f"{destination}: is the recording itself; write the corrected copy elsewhere")
    if kind in BAGS:
        from ..io.output_paths import write_target

        # A bag directory is new (never replaced); a single storage file replaces a file, through a symlink.
        target = Path(destination) if kind == "rosbag2" else write_target(destination)
        if kind == "rosbag2" and os.path.lexists(target):
            raise RecordingError(f"{destination}: already exists (rosbag2 writes a new directory)")
        if kind != "rosbag2" and target.is_dir():
            raise RecordingError(f"{destination}: is a directory; the corrected copy of a single {kind} file "
                                 "is a file")
        scratch = _scratch_beside(target)
        try:
            bag = scratch / (target.name if kind == "rosbag2" else target.stem)
            written = write_corrected_bag(replay, calibration, bag)
            if kind == "rosbag2":
                staged, move = bag, rename_no_replace
            else:
                files = [f for f in bag.iterdir() if f.suffix in (".mcap", ".db3")]
                if len(files) != 1:
                    raise RecordingError(f"{destination}: the corrected bag came out as {len(files)} files, "
                                         "expected one")
                staged, move = files[0], os.replace
        except BaseException:
            shutil.rmtree(scratch, ignore_errors=True)
            raise

        def put_in_place() -> None:
            try:
                move(staged, target)
            except OSError as error:
                raise RecordingError(f"cannot write {destination}: {error.strerror or error}") from None

        what = "bag" if kind == "rosbag2" else f"{kind} file"
        return StagedCopy(f"corrected {what} {destination} ({written} messages; {replay.source.imu_topic} corrected)",
                          put_in_place, scratch)
    from ..io.calibration_file import write_text_atomically
    from .csv_stream import corrected_csv_text, samples_csv_text

    assert isinstance(recording, Recording), "anything but a bag is read whole"
    # The filtered temperature held at each sample (NaN where none or stale), as the correction uses it.
    temperatures = None if replay.temperatures is None else replay.temperatures.at(recording.t_ns)
    rates: np.ndarray | None
    gyro = recording.gyro_radps if recording.gyro_radps is not None else np.zeros_like(recording.accel_mps2)
    corrected, rates, _, _, valid = corrected_samples(replay, calibration, recording.t_ns, recording.accel_mps2, gyro)
    if recording.gyro_radps is None:
        rates = None
    if kind == "csv":
        assert recording.source is not None, "a CSV recording carries its layout"
        text = corrected_csv_text(recording.path, recording.source, corrected, valid, rates)
        line = f"corrected CSV {destination} ({len(corrected)} samples; ax,ay,az corrected, in the file's units)"
    else:
        text = samples_csv_text(recording.t_ns, corrected, rates, temperatures)
        line = (f"corrected samples {destination} (CSV t_ns,ax,ay,az,...: a ULog is not rewritten; "
                f"{len(corrected)} samples)")
    return StagedCopy(line, lambda: write_text_atomically(destination, text))
