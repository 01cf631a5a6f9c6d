"""Launch the online accelerometer calibration node.

    ros2 launch accel_calibration calibration.launch.py
    ros2 launch accel_calibration calibration.launch.py namespace:=uav1 imu_topic:=/sensors/imu/raw \
        params_file:=/path/to/my_params.yaml

The installed config/accel_calibration.yaml uses the `/**:` wildcard block, so it applies under any
namespace and node name. Topic arguments are remappings of the node's relative topic names.
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

PACKAGE = "accel_calibration"


def generate_launch_description() -> LaunchDescription:
    default_params = os.path.join(get_package_share_directory(PACKAGE), "config", "accel_calibration.yaml")

    namespace = LaunchConfiguration("namespace")
    params_file = LaunchConfiguration("params_file")
    imu_topic = LaunchConfiguration("imu_topic")
    temperature_topic = LaunchConfiguration("temperature_topic")
    output_topic = LaunchConfiguration("output_topic")
    armed_topic = LaunchConfiguration("armed_topic")

    return LaunchDescription([
        DeclareLaunchArgument("namespace", default_value="", description="Namespace of the node"),
        DeclareLaunchArgument("params_file", default_value=default_params,
                              description="ROS 2 parameters file for the node"),
        DeclareLaunchArgument("imu_topic", default_value="imu/data_raw",
                              description="Raw sensor_msgs/Imu input"),
        DeclareLaunchArgument("temperature_topic", default_value="imu/temperature",
                              description="sensor_msgs/Temperature input of the IMU die"),
        DeclareLaunchArgument("output_topic", default_value="imu/data_calibrated",
                              description="Calibrated sensor_msgs/Imu output"),
        DeclareLaunchArgument("armed_topic", default_value="armed",
                              description="std_msgs/Bool, true while armed or flying: nothing is collected"),
        Node(
            package=PACKAGE,
            executable="calibration_node",
            name="accel_calibration",
            namespace=namespace,
            parameters=[params_file],
            remappings=[
                ("imu/data_raw", imu_topic),
                ("imu/temperature", temperature_topic),
                ("imu/data_calibrated", output_topic),
                ("armed", armed_topic),
            ],
            output="screen",
            emulate_tty=True,
        ),
    ])
