"""End-to-end replay of a 1 kHz bag of 150k IMU messages (plus temperature at 10 Hz) against merely
reading and deserializing the same IMU messages one by one with rosbags, in the same run, for both
storages. Target (issue 5): replay >= 3x faster."""
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from accel_calibration.bag.bag_io import write_session_bag
from accel_calibration.bag.replay import replay_bag
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations


def rosbags_one_by_one(path) -> int:
    count = 0
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        connections = [c for c in reader.connections if c.msgtype == "sensor_msgs/msg/Imu"]
        for connection, _, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, connection.msgtype)
            count += msg.header.stamp.nanosec >= 0
    return count


def best_of(fn, repeat=3) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> int:
    rng = np.random.default_rng(0)
    errors = SensorErrors.mpu6050_like(rng)
    imu = SyntheticImu(errors, spread_orientations(46, rng), dwell_s=2.2, move_s=1.2, rate_hz=1000.0, seed=0)
    samples = imu.samples()
    assert len(samples.t_ns) >= 150_000
    with tempfile.TemporaryDirectory() as tmp:
        for storage in ("sqlite3", "mcap"):
            bag = Path(tmp) / f"session_{storage}"
            write_session_bag(bag, samples, start_ns=1_700_000_000 * 10**9, storage=storage)
            baseline = best_of(lambda bag=bag: rosbags_one_by_one(bag))
            replay = best_of(lambda bag=bag: replay_bag(bag))
            result = replay_bag(bag)
            assert result.calibration is not None, result.problem
            n = len(samples.t_ns)
            print(f"{storage:7s}: {n} IMU messages; rosbags read+deserialize {baseline:.2f} s "
                  f"({baseline / n * 1e6:.1f} us/msg), "
                  f"replay end-to-end {replay:.2f} s ({replay / n * 1e6:.1f} us/msg, {len(result.poses)} poses, "
                  f"fit {result.calibration.quality.residual_rms_mg:.2f} mg): {baseline / replay:.1f}x faster "
                  "(target >= 3x)")
            shutil.rmtree(bag)
    return 0


if __name__ == "__main__":
    sys.exit(main())
