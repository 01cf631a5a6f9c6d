"""Bag replay: real rosbag2 files in both storages, written here with rosbags and read back."""
from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
import rclpy
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from accel_calibration import load_calibration, save_calibration
from accel_calibration.bag.imu_messages import decode_imus
from accel_calibration.bag.replay import replay_bag
from accel_calibration.cli.main import main
from msg_tools.bag_writer import write_session_bag
from msg_tools.calibration_client import CalibrationClient
from msg_tools.node_process import NodeProcess, installed_command
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

from helpers.one_line import assert_one_error_line

ACCEL_CALIB = installed_command("accel-calib")
START_NS = 1_700_000_000 * 10**9


def session(seed=1, poses=16):
    rng = np.random.default_rng(seed)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    imu = SyntheticImu(errors, spread_orientations(poses, rng), dwell_s=2.5, move_s=1.0, rate_hz=200.0, seed=seed)
    return errors, imu.samples()


def read_all(path):
    with AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        return [(c.topic, t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages()]


@pytest.mark.parametrize("name", ["sunsided_full_sphere_imu_temp_sqlite3", "sunsided_full_sphere_imu_temp_mcap_zstd",
                                  "test2_sqlite3", "test2_mcap_zstd"])
def test_bulk_decoder_matches_rosbags_on_real_bags(shared, name):
    with AnyReader([shared(f"real/bags/{name}")], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        connection = next(c for c in reader.connections if c.msgtype == "sensor_msgs/msg/Imu")
        raws = [raw for _, _, raw in reader.messages(connections=[connection])]
        t, accel, gyro, frame_id, groups, *_ = decode_imus(raws, name, reader.deserialize)
        assert groups  # the bulk path was taken
        for i in range(0, len(raws), 37):
            msg = reader.deserialize(raws[i], connection.msgtype)
            assert t[i] == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            a, w = msg.linear_acceleration, msg.angular_velocity
            assert tuple(accel[i]) == (a.x, a.y, a.z) and tuple(gyro[i]) == (w.x, w.y, w.z)
        assert frame_id == msg.header.frame_id


@pytest.mark.parametrize("name", ["test2_sqlite3", "test2_mcap_zstd"])
def test_real_drive_without_a_pose_session_is_refused_in_one_line(shared, name):
    run = subprocess.run([*ACCEL_CALIB, "replay", shared(f"real/bags/{name}")], capture_output=True, text=True,
                         check=False)
    assert_one_error_line(run.returncode, run.stderr, "too few static poses", "no multi-pose session")
    assert "/imu/data (3061 messages, 61.2 s)" in run.stderr


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_replay_calibrates_and_writes_a_corrected_bag(tmp_path, storage):
    errors, samples = session()
    bag = tmp_path / "session"
    write_session_bag(bag, samples, start_ns=START_NS, storage=storage, shuffle_seed=7)  # out of order on disk
    out = tmp_path / "corrected"
    assert main(["replay", str(bag), "-o", str(tmp_path / "cal.yaml"), "--corrected-bag", str(out),
                 "--report", str(tmp_path / "report.png")]) == 0
    cal = load_calibration(tmp_path / "cal.yaml")
    # Within 4 sigma of the fit's own uncertainty (which the Monte Carlo test shows to be honest).
    assert np.all(np.abs(cal.bias - errors.bias_mps2) <= 4 * cal.bias_sigma)
    assert np.all(np.abs(cal.matrix - errors.matrix) <= 4 * cal.matrix_sigma + 1e-12)
    assert cal.frame_id == "imu_link" and cal.gyro_bias_radps is not None

    before, after = read_all(bag), read_all(out)
    assert len(before) == len(after) and [m[:2] for m in before] == [m[:2] for m in after]
    raw_imu = [m for topic, _, m in before if topic == "/imu/data_raw"]
    new_imu = [m for topic, _, m in after if topic == "/imu/data_raw"]
    raw = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] for m in raw_imu])
    new = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] for m in new_imu])
    np.testing.assert_allclose(new, cal.apply(raw), rtol=0, atol=1e-12)
    for a, b in zip(raw_imu[::50], new_imu[::50]):  # everything else unchanged
        assert a.header.stamp == b.header.stamp and a.header.frame_id == b.header.frame_id
        # The gyro's bias and, when the motions allowed it, its matrix come off as the node applies them
        # (core.correction's one correction; Calibration.apply_gyro goes through BLAS: 1e-15).
        rate = [a.angular_velocity.x, a.angular_velocity.y, a.angular_velocity.z]
        np.testing.assert_allclose([b.angular_velocity.x, b.angular_velocity.y, b.angular_velocity.z],
                                   cal.apply_gyro(rate), rtol=0, atol=1e-15)
    temperatures = [(t, m.temperature) for topic, t, m in before if topic == "/imu/temperature"]
    assert temperatures == [(t, m.temperature) for topic, t, m in after if topic == "/imu/temperature"]
    # The corrected recording, replayed, needs no further correction.
    again = replay_bag(out)
    # To 0.1 ug, not 1e-9: the poses are weighted by their own noise, whose sample covariance M
    # reshapes pose by pose (it is not quite isotropic), so the copy's weights differ by ~1e-3 (~0.04 ug here).
    assert np.abs(again.calibration.bias).max() < 1e-6
    assert (tmp_path / "report.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.ros
def test_replay_gives_the_calibration_the_live_node_gives(tmp_path):
    errors, samples = session(seed=4)
    bag = tmp_path / "recorded"
    write_session_bag(bag, samples, start_ns=START_NS, storage="mcap")
    replayed = replay_bag(bag)
    assert replayed.calibration is not None

    rclpy.init()
    cal_file = tmp_path / "live.yaml"
    node = NodeProcess(cal_file)
    client = CalibrationClient()
    try:
        client.wait_ready()
        sent = client.play(samples, start_ns=START_NS)
        assert client.settle(sent)  # every message arrived: the node saw exactly the recorded session
        answer = client.call("calibrate")
        assert answer.success, answer.message
    finally:
        client.destroy()
        rclpy.shutdown()
        assert node.stop() == 0, node.log()
    live = load_calibration(cal_file)
    assert len(replayed.poses) >= 12
    # Same poses, same store, same cold fit at /calibrate: equal (the node's warm refits do not decide).
    np.testing.assert_allclose(live.bias, replayed.calibration.bias, rtol=0, atol=1e-9)
    np.testing.assert_allclose(live.matrix, replayed.calibration.matrix, rtol=0, atol=1e-10)


def test_several_bags_in_parallel_with_a_comparison_table(tmp_path, capsys):
    bags = []
    for seed in (11, 12):
        _, samples = session(seed=seed)  # a different badly calibrated part each time
        bags.append(tmp_path / f"flight{seed}")
        write_session_bag(bags[-1], samples, start_ns=START_NS, storage="sqlite3")
    assert main(["replay", *map(str, bags), "--jobs", "2", "-o", str(tmp_path / "cals")]) == 0
    out = capsys.readouterr().out
    assert "flight11" in out and "flight12" in out and "spread (1 sigma across bags)" in out
    for bag in bags:
        assert load_calibration(tmp_path / "cals" / f"{bag.name}.yaml").quality.poses >= 12


def test_report_from_a_poses_table(tmp_path):
    errors, samples = session(seed=5)
    bag = tmp_path / "b"
    write_session_bag(bag, samples, start_ns=START_NS)
    replay = replay_bag(bag)
    save_calibration(replay.calibration, tmp_path / "cal.yaml")
    rows = ["ax,ay,az"] + [",".join(f"{v:.9f}" for v in p.accel_mps2) for p in replay.poses]
    (tmp_path / "poses.csv").write_text("\n".join(rows) + "\n")
    assert main(["report", str(tmp_path / "cal.yaml"), "--poses", str(tmp_path / "poses.csv"),
                 "-o", str(tmp_path / "r.png")]) == 0
    assert main(["report", str(tmp_path / "cal.yaml"), "--bag", str(bag), "-o", str(tmp_path / "r2.png")]) == 0
    assert (tmp_path / "r.png").stat().st_size > 20_000


def test_bag_errors_are_one_line(tmp_path, capsys):
    _, samples = session(seed=6, poses=3)
    only_temperature = tmp_path / "no_imu"
    write_session_bag(only_temperature, samples, start_ns=START_NS, imu_topic="/other")
    for args, message in [
        (["replay", str(tmp_path / "absent")], "no such bag"),
        (["replay", str(only_temperature), "--imu-topic", "/imu/data_raw"],
         "no sensor_msgs/msg/Imu topic /imu/data_raw; the bag has"),
        (["replay", str(only_temperature), "--jobs", "0"], "--jobs"),
    ]:
        assert main(args) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "metadata.yaml").write_text("not: a bag\n")
    assert main(["replay", str(tmp_path / "junk")]) == 1
    assert "not a readable rosbag2" in capsys.readouterr().err


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_direct_read_and_rosbags_read_give_the_same_poses(tmp_path, storage):
    _, samples = session(seed=9)
    bag = tmp_path / "b"
    write_session_bag(bag, samples, start_ns=START_NS, storage=storage, shuffle_seed=2)
    fast, through_rosbags = replay_bag(bag), replay_bag(bag, through_rosbags=True)
    assert len(fast.poses) == len(through_rosbags.poses) >= 12
    for a, b in zip(fast.poses, through_rosbags.poses):
        assert (a.start_ns, a.end_ns, a.samples) == (b.start_ns, b.end_ns, b.samples)
        np.testing.assert_array_equal(a.accel_mps2, b.accel_mps2)
    np.testing.assert_array_equal(fast.calibration.bias, through_rosbags.calibration.bias)


def test_a_clean_recording_reports_nothing_skipped(tmp_path, capsys):
    """Found by the docs audit: every replay printed 'skipped: samples N' (the informational count of
    samples read, as if they had been skipped)."""
    rng = np.random.default_rng(12)
    samples = SyntheticImu(SensorErrors.mpu6050_like(rng), spread_orientations(14, rng), dwell_s=2.0, move_s=0.5,
                           rate_hz=200.0, seed=12).samples()
    write_session_bag(tmp_path / "bag", samples, start_ns=START_NS, storage="mcap")
    assert main(["replay", str(tmp_path / "bag"), "-o", str(tmp_path / "cal.yaml")]) == 0
    out = capsys.readouterr().out
    assert "skipped" not in out, out


def test_replay_says_and_keeps_the_white_noise_measured_at_the_poses(tmp_path, capsys):
    """The densities Kalibr's imu.yaml takes (sigma / sqrt(rate)): said in one line and kept in the file,
    the simulated 0.04 m/s^2 per sample at 200 Hz within 15 %."""
    rng = np.random.default_rng(12)
    errors = SensorErrors.mpu6050_like(rng)
    samples = SyntheticImu(errors, spread_orientations(14, rng), dwell_s=2.0, move_s=0.5, rate_hz=200.0,
                           seed=12).samples()
    write_session_bag(tmp_path / "bag", samples, start_ns=START_NS, storage="mcap")
    assert main(["replay", str(tmp_path / "bag"), "-o", str(tmp_path / "cal.yaml")]) == 0
    said = [line for line in capsys.readouterr().out.splitlines() if line.startswith("white noise at the poses")]
    noise = load_calibration(tmp_path / "cal.yaml").noise
    assert said == [noise.describe()] and noise.rate_hz == 200.0
    assert abs(noise.accel_density * np.sqrt(200.0) / errors.noise_mps2 - 1) < 0.15
