"""What touches ROS messages: conversions, the synthetic IMU and its publisher, bag helpers."""
