"""The calibration core: numpy/scipy only (no ROS, no rosbags, no file formats).

settings, screening, detector, pose store, fit, gates, calibration, correction and the session
that owns the chain. Imported by io, bag, ros and cli; imports none of them."""
