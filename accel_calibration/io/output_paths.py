"""Where a command may write, and how: never over one of its own inputs (the same file by any name:
a symlink, a hard link, a path inside an input bag), never over something that is not a regular file,
and always whole (temp file beside the real target + rename), keeping the replaced file's mode.

Every command (`fit`, `apply`, `report`, `replay`) and the node's save go through here."""
from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path

from ..core.errors import CalibrationError


class OutputPathError(CalibrationError):
    """io: an output that would destroy an input or cannot be written (the message names both paths)."""


def temp_prefix(path: Path) -> str:
    """Prefix of our temp files beside `path` (`.<name>.*.tmp`), so stale ones can be found and removed."""
    return f".{path.name}."


def write_target(path: str | os.PathLike[str]) -> Path:
    """The file a write to `path` lands in: symlinks followed to their final target (a dangling link
    gives the file it names), so a symlinked output is replaced at its target, the link kept."""
    return Path(os.path.realpath(path))


def _stat(path: str | os.PathLike[str]) -> os.stat_result | None:
    try:
        return os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError:
        return None


def _inside(child: Path, parent: Path) -> bool:
    return child == parent or parent in child.parents


def check_outputs(outputs: Sequence[tuple[str, str | os.PathLike[str] | None]],
                  inputs: Iterable[str | os.PathLike[str] | None],
                  directories: Iterable[str] = ()) -> None:
    """Refuse, before any work, outputs that are an input (same (st_dev, st_ino), through symlinks and
    hard links too), lie inside an input directory (a bag), repeat each other, or exist but are not
    regular files. `outputs` are (label as the user typed it, path); labels in `directories` name
    outputs that are directories (created new, or holding one file per bag)."""
    directory_labels = set(directories)
    real_inputs = []
    for path in inputs:
        if path is None:
            continue
        info = _stat(path)
        real_inputs.append((str(path), write_target(path), info))
    seen: dict[Path, str] = {}
    for label, output in outputs:
        if output is None:
            continue
        target = write_target(output)
        info = _stat(target)
        if label not in directory_labels and info is not None and not stat.S_ISREG(info.st_mode):
            kind = "a directory" if stat.S_ISDIR(info.st_mode) else "not a regular file"
            raise OutputPathError(f"{label} {output} is {kind}: give a file name to write")
        for name, real, input_info in real_inputs:
            same = (info is not None and input_info is not None
                    and (info.st_dev, info.st_ino) == (input_info.st_dev, input_info.st_ino))
            if same or target == real:
                raise OutputPathError(f"{label} {output} is the input {name} itself: writing it would destroy "
                                      "the input; choose another output")
            if input_info is not None and stat.S_ISDIR(input_info.st_mode) and _inside(target, real):
                raise OutputPathError(f"{label} {output} lies inside the input {name}: writing there would change "
                                      "the recording; choose an output outside it")
        if target in seen:
            raise OutputPathError(f"{label} {output} is also {seen[target]}: give each output its own path")
        seen[target] = f"{label} {output}"


def check_output_places(outputs: Sequence[tuple[str, str | os.PathLike[str] | None]]) -> None:
    """Refuse, before any work, outputs whose directory does not exist (or is not a directory): each
    (label as the user typed it, path)."""
    for label, output in outputs:
        if output is None:
            continue
        parent = write_target(output).parent
        if not parent.is_dir():
            raise OutputPathError(f"{label} {output}: directory {parent} does not exist; make it first")


def _umask() -> int:
    """The process umask without changing it (os.umask is process-wide and racy with threads)."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    return 0o022


def write_bytes_atomically(path: str | os.PathLike[str], data: bytes) -> None:
    """Write beside the real target and rename over it, so a reader (or a crash) never sees half a file
    and the old file stays whole when the write fails. A symlink is written through to its target (the
    link stays a link); the replaced file's permissions (and, where allowed, owner) are kept; a new
    file gets 0666 less the umask. The temp file is removed on any failure, an interrupt included."""
    target = write_target(path)
    directory = target.parent
    info = _stat(target)
    if info is not None and not stat.S_ISREG(info.st_mode):
        raise OutputPathError(f"cannot write {path}: it exists and is not a regular file")
    tmp_name = None
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=temp_prefix(target), suffix=".tmp", dir=directory)
        with os.fdopen(fd, "wb") as tmp:
            if info is not None:
                try:
                    os.fchown(tmp.fileno(), info.st_uid, info.st_gid)  # before chmod: chown clears set-id bits
                except OSError:
                    pass  # not ours to give away: the writer's ownership, the mode still kept
                os.fchmod(tmp.fileno(), stat.S_IMODE(info.st_mode))
            else:
                os.fchmod(tmp.fileno(), 0o666 & ~_umask())
            tmp.write(data)
            tmp.flush()
            os.fsync(tmp.fileno())
        os.replace(tmp_name, target)
        tmp_name = None
        _fsync_directory(directory)
    except OSError as error:
        raise OutputPathError(f"cannot write {path}: {error.strerror or error}") from None
    finally:
        if tmp_name is not None:
            try:
                os.unlink(tmp_name)
            except OSError:
                pass


def _fsync_directory(directory: Path) -> None:
    """Make the rename itself durable; best effort (some filesystems refuse to open a directory)."""
    try:
        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def stale_temp_files(path: str | os.PathLike[str]) -> list[Path]:
    """Temp files a killed writer left beside `path` or beside its symlink target."""
    path = Path(path)
    places = {path, write_target(path)}
    found: list[Path] = []
    for place in places:
        try:
            found.extend(place.parent.glob(temp_prefix(place) + "*.tmp"))
        except OSError:
            continue
    return sorted(set(found))
