"""The stream side: samples in arrays (a recording in parts, the node's buffer) -> screening
(screening.py), temperature filter (temperature_filter.py), detector (detector.py: the clocks;
detector_batch.py: the rules, over a frozen config and a state it owns; noise_floor.py) -> still
intervals as Poses, fed by RecordingFeed (feed.py) through the session's public API."""
