"""The stream side: samples in arrays (a recording in parts, the node's buffer) -> screening
(screening.py), temperature filter (temperature_filter.py), detector (detector.py: the clocks;
detector_batch.py: the rules, over a frozen config and a state it owns; noise_floor.py) -> still
intervals as Poses, and the raw gyro between them (motion_recorder.py). `StreamSide` (stream_side.py)
holds these parts, takes a part through them (`take`) and judges which interval is a pose;
`RecordingFeed` (feed.py) cuts a recording into parts and hands them to it. Nothing
here imports the session that composes it."""
