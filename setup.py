from glob import glob

from setuptools import find_packages, setup

package_name = "accel_calibration"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(include=[package_name, package_name + ".*", "msg_tools"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/launch", glob("launch/*.py")),
    ],
    # Every third-party import of accel_calibration/ and msg_tools/ (ROS message packages and rclpy come
    # from package.xml / rosdep). rosbags has no rosdep key, so it is only declared here; lz4 and
    # backports.zstd are imported directly by bag/mcap_scan.py for compressed MCAP chunks.
    install_requires=[
        "setuptools",
        "numpy",
        "scipy",
        "PyYAML",
        "rosbags",
        "lz4",
        'backports.zstd; python_version < "3.14"',
        "matplotlib",
        "tqdm",
        # accel-calib replay of PX4 logs (bag/ulog_reader.py) and CSV sample streams (bag/csv_stream.py).
        "pyulog",
        "pyarrow",
        # ArduPilot DataFlash logs: replay (bag/dataflash.py) and compare's PARM records (io/autopilot_params.py).
        "pymavlink",
        # accel-calib fleet and history (cli/fleet.py, io/history.py): Dask distributed and SQLAlchemy 2.
        "dask[distributed]",
        "distributed",
        "SQLAlchemy>=2",
        "regex",  # --vehicle rules matched under a time limit
    ],
    # A history on a shared PostgreSQL (--history postgresql://...): SQLAlchemy loads this driver for such
    # URLs; nothing imports it otherwise. pip install accel_calibration[postgresql].
    extras_require={"postgresql": ["psycopg[binary]>=3.1"]},
    zip_safe=True,
    maintainer="accel_calibration developers",
    maintainer_email="dev@accel-calibration.invalid",
    description="Online MEMS accelerometer calibration for ROS 2",
    license="BSD-3-Clause",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "accel-calib = accel_calibration.cli.main:main",
            "calibration_node = accel_calibration.ros.node:main",
        ],
    },
)
