"""The calibration file the node's work keeps, without ROS: load, save, and the guard against another writer.

Loaded at start (and checked for plausibility: a file that is not ours, or is implausible, is left
untouched and never overwritten); a new calibration is saved first and held as the calibration in force
only once saved, so what runs is always what the file says (the work then hands it to the stream side's
correction, live/in_force.py). A file changed underneath by another writer is refused once, not
overwritten unnoticed.
"""
from __future__ import annotations

import enum
import hashlib
import os
import stat
from dataclasses import dataclass
from pathlib import Path

from ..core.calibration import Calibration
from ..core.errors import CalibrationError
from ..core.fit_result import ParameterSource
from ..core.plausibility import implausible_text, plausibility_refusal
from ..core.settings import Settings
from ..io.calibration_file import MAX_CALIBRATION_BYTES, load_calibration, remove_stale_temp_files, save_calibration


class Level(enum.StrEnum):
    """The diagnostics' level of the calibration in force (a str: logs and tests read it as one)."""

    OK = "ok"
    WARN = "warn"
    ERROR = "error"


OK, WARN, ERROR = Level.OK, Level.WARN, Level.ERROR


@dataclass(frozen=True)
class FileIdentity:
    """What a calibration file was when this node last read or wrote it: its stat, and its content's
    digest (a rewrite of the same bytes is no change)."""

    device: int
    inode: int
    size: int
    mtime_ns: int
    digest: bytes

    @classmethod
    def of(cls, path: Path) -> FileIdentity | None:
        """None when there is no file (or it cannot be read: then nothing of it is known)."""
        try:
            info = os.stat(path)
            if not stat.S_ISREG(info.st_mode):  # a FIFO would block the open: its stat must do
                return cls(info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns, b"")
            with open(path, "rb") as file:  # the node's file is at most 1 MiB (checked before it is loaded)
                digest = hashlib.sha256(file.read(MAX_CALIBRATION_BYTES + 1)).digest()
        except OSError:
            return None
        return cls(info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns, digest)

    def same_content(self, other: FileIdentity | None) -> bool:
        return other is not None and (self == other or (self.size == other.size and self.digest == other.digest))


def _same(known: FileIdentity | None, now: FileIdentity | None) -> bool:
    return now is None if known is None else known.same_content(now)


class CalibrationStore:
    def __init__(self, path: Path, settings: Settings):
        self.path = path
        self.settings = settings
        self.calibration: Calibration | None = None  # the calibration in force: the file's, as loaded or saved
        self.file_unreadable = False  # a file we could not read is never overwritten
        # The file as this node last loaded or saved it (None: no file), and a change it already reported:
        # the same call again overwrites that change on purpose.
        self._file: FileIdentity | None = None
        self._reported: tuple[FileIdentity | None] | None = None
        self.changed_underneath: str | None = None  # why the last save was refused, while it holds

    def remove_stale_temp_files(self) -> int:
        return remove_stale_temp_files(self.path)

    def load(self) -> tuple[Level, str]:
        """Load the file at start: (level, what happened, one line)."""
        self._file = FileIdentity.of(self.path)
        if not self.path.exists():
            return WARN, f"no calibration file at {self.path}: raw acceleration passes through until calibrated"
        try:
            calibration = load_calibration(self.path)
            refusal = plausibility_refusal(calibration, max_bias_mps2=self.settings.max_bias_mps2,
                                           scale_band=(self.settings.scale_min, self.settings.scale_max),
                                           gyro_scale_band=(self.settings.gyro_scale_min, self.settings.gyro_scale_max))
            if refusal is not None:
                raise CalibrationError(f"{self.path}: implausible for an accelerometer in m/s^2 "
                                       f"({implausible_text(refusal)})")
        except CalibrationError as error:
            self.file_unreadable = True
            return ERROR, f"calibration file unusable, left untouched, raw passes through: {error}"
        self.calibration = calibration
        quality = calibration.quality
        text = f"residual {quality.residual_rms_mg:.2f} mg rms over {quality.poses} poses" if quality else \
            "no quality recorded"
        return OK, f"loaded calibration from {self.path} ({calibration.model}, {text})"

    def save_then_apply(self, calibration: Calibration, asked: bool = True,
                        parameter_sources: tuple[ParameterSource, ...] = (), prior: str | None = None
                        ) -> tuple[bool, str]:
        """Save first, then hold as in force: a calibration that could not be saved is not applied. `asked`:
        a person's call (a file changed underneath is overwritten when the call is repeated), not
        auto_calibrate (which never overwrites a change it did not make). A fit with a prior: the file says
        which parameters came from the poses and which from `prior`."""
        refusal = self._unwritable(asked)
        if refusal is not None:
            return False, refusal
        try:
            self._save(calibration, parameter_sources, prior)
        except CalibrationError as error:
            return False, f"not applied: {error}; {self.kept()}"
        self.calibration = calibration
        return True, f"saved to {self.path}"

    def save(self) -> tuple[bool, str]:
        """calibration/save: the calibration in force to the file again."""
        calibration = self.calibration
        if calibration is None:
            return False, "no calibration in force to save"
        refusal = self._unwritable(asked=True)
        if refusal is not None:
            return False, refusal
        try:
            self._save(calibration)
        except CalibrationError as error:
            return False, str(error)
        return True, f"saved to {self.path}"

    def kept(self) -> str:
        return "previous calibration kept in force" if self.calibration is not None else \
            "no calibration in force: raw passes through"

    def _unwritable(self, asked: bool = True) -> str | None:
        if self.file_unreadable:
            return (f"{self.path} holds a file this node could not read (foreign or corrupt); it is left "
                    "untouched: move it away or set calibration_file")
        return self._changed_since(asked)

    def _changed_since(self, asked: bool) -> str | None:
        """Another writer of this file (a node with the same calibration_file, a replay's -o) would be
        overwritten unnoticed, and the calibration in force would no longer be the file's: refuse once.
        A file removed meanwhile holds nothing to lose: it is written again."""
        now = FileIdentity.of(self.path)
        if now is None or _same(self._file, now) or (
                asked and self._reported is not None and _same(self._reported[0], now)):
            self.changed_underneath = None
            return None
        if asked:
            self._reported = (now,)
        again = "the same call again overwrites it" if asked else "call /calibrate to overwrite it"
        self.changed_underneath = (f"not saved: {self.path} changed since this node loaded or saved it (another node "
                                   "or a replay writing the same file?), so the calibration in force is no longer "
                                   f"the file's; the file is left as it is, {self.kept()}; {again}")
        return self.changed_underneath

    def _save(self, calibration: Calibration, parameter_sources: tuple[ParameterSource, ...] = (),
              prior: str | None = None) -> None:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise CalibrationError(f"cannot create {self.path.parent}: {error.strerror}") from None
        save_calibration(calibration, self.path, parameter_sources, prior)
        self._file, self._reported, self.changed_underneath = FileIdentity.of(self.path), None, None
