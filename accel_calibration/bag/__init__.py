"""Recordings: rosbag2 readers that yield sample arrays, the replay driver, the corrected-bag writer."""
