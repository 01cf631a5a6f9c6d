"""Where a command may write, and how: never over one of its own inputs (the same file by any name:
a symlink, a hard link, a path inside an input bag), never over something that is not a regular file,
and always whole (temp file beside the real target + rename), keeping the replaced file's mode.

Every command (`fit`, `apply`, `report`, `replay`) and the node's save go through here."""
from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Callable, Iterable, Mapping, Sequence
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


def _staged(target: Path, data: bytes, info: os.stat_result | None) -> str:
    """`data` in a temp file beside `target`, flushed to disk, with the mode (and, where allowed, owner) of the
    file it will replace, or 0666 less the umask; its name. Removed again on any failure, an interrupt included."""
    fd, tmp_name = tempfile.mkstemp(prefix=temp_prefix(target), suffix=".tmp", dir=target.parent)
    try:
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
    except BaseException:
        _remove(tmp_name)
        raise
    return tmp_name


def _remove(path: str | Path) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def write_bytes_atomically(path: str | os.PathLike[str], data: bytes) -> None:
    """Write beside the real target and rename over it, so a reader (or a crash) never sees half a file
    and the old file stays whole when the write fails. A symlink is written through to its target (the
    link stays a link); the replaced file's permissions (and, where allowed, owner) are kept; a new
    file gets 0666 less the umask. The temp file is removed on any failure, an interrupt included."""
    target = write_target(path)
    info = _stat(target)
    if info is not None and not stat.S_ISREG(info.st_mode):
        raise OutputPathError(f"cannot write {path}: it exists and is not a regular file")
    tmp_name = None
    try:
        tmp_name = _staged(target, data, info)
        os.replace(tmp_name, target)
        tmp_name = None
        _fsync_directory(target.parent)
    except OSError as error:
        raise OutputPathError(f"cannot write {path}: {error.strerror or error}") from None
    finally:
        if tmp_name is not None:
            _remove(tmp_name)


def check_replaceable(paths: Iterable[Path], replaceable: Callable[[Path], bool], what: str) -> None:
    """Refuse an existing file among `paths` that is not a regular file or not `what` (`replaceable` says)."""
    for path in paths:
        info = _stat(write_target(path))
        if info is None:
            continue
        if not stat.S_ISREG(info.st_mode) or not replaceable(path):
            raise OutputPathError(f"{path} exists and is not {what}: not replaced; move it away or write "
                                  "elsewhere")


def write_set_atomically(files: Mapping[Path, bytes], replaceable: Callable[[Path], bool],
                         what: str) -> list[tuple[Path, bool]]:
    """Write a set of files as one: every file staged beside its target first (temp file, on disk), then all
    renamed into place; a failure anywhere leaves every file of the earlier set as it was (the ones already
    renamed are put back from hard links taken before). An existing file that is not `what` (`replaceable`
    says) is never replaced. Returns (path, whether it replaced a file) per file."""
    check_replaceable(files, replaceable, what)
    targets = {path: write_target(path) for path in files}
    staged: dict[Path, str] = {}
    kept: dict[Path, str | None] = {}  # the earlier file, as a hard link beside it (None: there was none)
    placed: list[Path] = []
    failed: Path | None = None
    try:
        for path, data in files.items():
            failed = path
            staged[path] = _staged(targets[path], data, _stat(targets[path]))
        for path in files:
            failed = path
            kept[path] = _kept(targets[path])
        for path in files:
            failed = path
            os.replace(staged[path], targets[path])
            del staged[path]
            placed.append(path)
    except OSError as error:
        _put_back(placed, targets, kept)
        raise OutputPathError(f"cannot write {failed}: {error.strerror or error}; none of the {len(files)} files "
                              f"written, the files there as they were") from None
    finally:
        for tmp_name in staged.values():
            _remove(tmp_name)
        for path, link in kept.items():  # a placed file's link was put back (or, after a success, is not needed)
            if link is not None and (path not in placed or len(placed) == len(files)):
                _remove(link)
    for directory in {target.parent for target in targets.values()}:
        _fsync_directory(directory)
    return [(path, kept[path] is not None) for path in files]


def _kept(target: Path) -> str | None:
    """A hard link to the file at `target` (a temp name beside it), to put it back if the set fails; None when
    there is no file."""
    info = _stat(target)
    if info is None:
        return None
    link = tempfile.mktemp(prefix=temp_prefix(target), suffix=".tmp", dir=target.parent)
    try:
        os.link(target, link)
    except OSError:  # a filesystem without hard links (FAT on an SD card): a copy instead
        return _staged(target, target.read_bytes(), info)
    return link


def _put_back(placed: list[Path], targets: Mapping[Path, Path], kept: Mapping[Path, str | None]) -> None:
    """Undo the renames of a set that failed: each earlier file back from its link, each new one removed."""
    for path in placed:
        link = kept.get(path)
        try:
            if link is None:
                os.unlink(targets[path])
            else:
                os.replace(link, targets[path])
        except OSError:
            pass  # best effort: the error already says the set failed


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
