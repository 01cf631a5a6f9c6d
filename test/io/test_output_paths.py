"""Outputs never destroy inputs: the same file by any name (symlink, hard link, a path inside an input
bag) is refused in one line before any work; a symlinked output is written through to its target,
whole; an existing file keeps its mode; several bags never overwrite each other's outputs."""
from __future__ import annotations

import os
import stat

import numpy as np
import pytest

from accel_calibration import Calibration, load_calibration, save_calibration
from accel_calibration.cli.main import main
from accel_calibration.io.output_paths import OutputPathError, check_outputs, write_bytes_atomically
from msg_tools.bag_writer import write_session_bag
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

from helpers.one_line import refused

G = 9.80665
START_NS = 1_700_000_000 * 10**9


def write_poses(path, seed=1, n=20):
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(n, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    directions[:6] = np.vstack([np.eye(3), -np.eye(3)])
    matrix = np.array([[1.02, 0, 0], [0.01, 0.98, 0], [-0.005, 0.008, 1.01]])
    raw = (G * directions) @ np.linalg.inv(matrix).T + [0.25, -0.4, 0.15] + rng.normal(0, 0.001, (n, 3))
    path.write_text("ax,ay,az\n" + "".join(",".join(f"{v:.9f}" for v in row) + "\n" for row in raw))
    return path


def session_bag(path, seed=11, poses=14, storage="sqlite3"):
    rng = np.random.default_rng(seed)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    imu = SyntheticImu(errors, spread_orientations(poses, rng), dwell_s=2.0, move_s=0.8, rate_hz=100.0, seed=seed)
    write_session_bag(path, imu.samples(), start_ns=START_NS, storage=storage)
    return path


@pytest.fixture
def files(tmp_path):
    poses = write_poses(tmp_path / "p.csv")
    cal = tmp_path / "cal.yaml"
    assert main(["fit", str(poses), "-o", str(cal)]) == 0
    data = tmp_path / "in.csv"
    data.write_text("ax,ay,az\n0.25,-0.4,10.0\n10.0,-0.4,0.15\n")
    return poses, cal, data


def snapshot(*paths):
    return {p: p.read_bytes() for p in paths}


def test_an_output_that_is_an_input_is_refused_and_nothing_changes(tmp_path, files, capsys):
    poses, cal, data = files
    os.symlink(poses, tmp_path / "poses-link.csv")
    os.link(data, tmp_path / "in-hardlink.csv")
    before = snapshot(poses, cal, data)
    cases = [
        (["apply", "-c", cal, data, data], "is the input"),
        (["apply", "-c", cal, data, cal], "is the input"),
        (["apply", "-c", cal, data, tmp_path / "in-hardlink.csv"], "is the input"),  # same inode
        (["apply", "-c", cal, data, tmp_path / "." / "in.csv"], "is the input"),
        (["fit", poses, "-o", poses], "is the input"),
        (["fit", poses, "-o", tmp_path / "poses-link.csv"], "is the input"),  # through a symlink
        (["report", cal, "--poses", poses, "-o", cal], "is the input"),
        (["report", cal, "--poses", poses, "-o", poses], "is the input"),
        (["apply", "-c", cal, data, tmp_path], "is a directory"),
        (["fit", poses, "-o", "/dev/null"], "not a regular file"),
    ]
    for args, message in cases:
        refused(capsys, args, message)
    assert snapshot(poses, cal, data) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.yaml", "in-hardlink.csv", "in.csv", "p.csv",
                                                          "poses-link.csv"]


def test_outputs_inside_a_bag_are_refused(tmp_path, capsys):
    bag = session_bag(tmp_path / "bag")
    before = {p.name: p.read_bytes() for p in bag.iterdir()}
    db3 = next(bag.glob("*.db3"))
    for args, message in [
        (["replay", bag, "-o", bag / "metadata.yaml"], "lies inside the input"),
        (["replay", bag, "--report", db3], "lies inside the input"),
        (["replay", bag, "--corrected-bag", bag / "copy"], "lies inside the input"),
        (["replay", bag, "-o", bag], "is a directory"),
        (["replay", bag, "-o", tmp_path / "x.yaml", "--report", tmp_path / "x.yaml"], "give each output its own"),
        (["report", tmp_path / "absent.yaml", "--bag", bag, "-o", bag / "r.png"], "lies inside the input"),
    ]:
        refused(capsys, args, message)
    assert {p.name: p.read_bytes() for p in bag.iterdir()} == before


def test_symlinked_output_is_written_through_to_its_target_whole_and_keeps_its_mode(tmp_path, files):
    poses, _, _ = files
    real = tmp_path / "real"
    real.mkdir()
    target = real / "cal.yaml"
    save_calibration(Calibration.identity(), target)
    os.chmod(target, 0o640)
    inode = target.stat().st_ino
    link = tmp_path / "current.yaml"
    os.symlink(os.path.relpath(target, tmp_path), link)  # relative, as people make them
    assert main(["fit", str(poses), "-o", str(link)]) == 0
    assert link.is_symlink() and os.path.realpath(link) == str(target)
    assert stat.S_IMODE(target.stat().st_mode) == 0o640
    assert target.stat().st_ino != inode  # replaced by a rename, not rewritten in place
    assert load_calibration(target).quality.poses == 20
    assert sorted(p.name for p in real.iterdir()) == ["cal.yaml"]  # no temp file beside the target
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.yaml", "current.yaml", "in.csv", "p.csv", "real"]


def test_a_dangling_symlink_creates_its_target(tmp_path, files):
    poses, _, _ = files
    os.symlink(tmp_path / "made.yaml", tmp_path / "link.yaml")
    assert main(["fit", str(poses), "-o", str(tmp_path / "link.yaml")]) == 0
    assert (tmp_path / "link.yaml").is_symlink() and load_calibration(tmp_path / "made.yaml").quality.poses == 20


@pytest.mark.parametrize("mode", [0o600, 0o644, 0o664, 0o400])
def test_replacing_keeps_the_mode_and_a_new_file_follows_the_umask(tmp_path, mode):
    path = tmp_path / "out.csv"
    path.write_text("old\n")
    os.chmod(path, mode)
    write_bytes_atomically(path, b"new\n")
    assert path.read_bytes() == b"new\n" and stat.S_IMODE(path.stat().st_mode) == mode
    previous = os.umask(0o027)
    try:
        write_bytes_atomically(tmp_path / "fresh.csv", b"x\n")
    finally:
        os.umask(previous)
    assert stat.S_IMODE((tmp_path / "fresh.csv").stat().st_mode) == 0o640


def test_check_outputs_by_identity_not_by_name(tmp_path):
    a = tmp_path / "a.csv"
    a.write_text("x\n")
    (tmp_path / "sub").mkdir()
    os.symlink(tmp_path, tmp_path / "sub" / "up")
    with pytest.raises(OutputPathError, match="is the input"):
        check_outputs([("output", tmp_path / "sub" / "up" / "a.csv")], [a])
    check_outputs([("output", tmp_path / "b.csv")], [a, None])  # a new file is fine
    with pytest.raises(OutputPathError, match="lies inside the input"):
        check_outputs([("output", tmp_path / "sub" / "up" / "sub" / "new.yaml")], [tmp_path / "sub"])


def test_bags_with_the_same_name_never_overwrite_each_other(tmp_path, capsys):
    bags = [session_bag(tmp_path / "a" / "flight", seed=11), session_bag(tmp_path / "b" / "flight", seed=12)]
    out = tmp_path / "cals"
    assert main(["replay", *map(str, bags), "-o", str(out), "--report", str(tmp_path / "reports")]) == 0
    printed = capsys.readouterr().out
    written = sorted(p.name for p in out.iterdir())
    assert len(written) == 2 and len(set(written)) == 2, written
    assert len(list((tmp_path / "reports").iterdir())) == 2
    biases = {tuple(load_calibration(out / name).bias) for name in written}
    assert len(biases) == 2  # two different parts, two different files
    for name in written:
        assert name.removesuffix(".yaml") in printed  # the comparison table tells them apart


def test_the_same_bag_twice_is_refused(tmp_path, capsys):
    bag = session_bag(tmp_path / "flight", poses=3)
    refused(capsys, ["replay", bag, tmp_path / "." / "flight", "-o", tmp_path / "cals"], "given twice")


def test_jobs_a_broken_bag_reports_one_line_and_the_others_finish(tmp_path, capsys):
    good = [session_bag(tmp_path / f"good{k}", seed=20 + k) for k in range(2)]
    broken = tmp_path / "broken"
    rng = np.random.default_rng(30)
    imu = SyntheticImu(SensorErrors.mpu6050_like(rng), spread_orientations(3, rng), dwell_s=2.0, move_s=0.8,
                       rate_hz=100.0, seed=30)
    write_session_bag(broken, imu.samples(), start_ns=START_NS, storage="mcap", chunk_compression="zstd")
    mcap = next(broken.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    data[len(data) // 3:len(data) // 3 + 64] = bytes(64)  # a damaged zstd chunk: the decompressor's own error
    mcap.write_bytes(bytes(data))
    out = tmp_path / "cals"
    code = main(["replay", str(good[0]), str(broken), str(good[1]), "--jobs", "2", "-o", str(out)])
    captured = capsys.readouterr()
    assert code == 1
    errors = captured.err.strip().splitlines()
    assert len(errors) == 1 and "broken" in errors[0] and "Traceback" not in captured.err, captured.err
    assert "good0" in captured.out and "good1" in captured.out
    assert sorted(p.name for p in out.iterdir()) == ["good0.yaml", "good1.yaml"]
