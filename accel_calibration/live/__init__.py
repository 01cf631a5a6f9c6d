"""The live node's work without ROS: the sample rings, the per-message side (correct, push), the calibration
work and the worker process it runs in (its protocol, its pace), the calibration in force. Imports io and
core; ros imports it."""
