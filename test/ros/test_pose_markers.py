"""calibration/markers over real DDS, as RViz or Foxglove would subscribe to it: the poses held as points on
the unit sphere at the orientations they were held in, the arrow where /diagnostics' advice says to turn,
and nothing stale after calibration/reset."""
from __future__ import annotations

import numpy as np
import pytest
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import Marker, MarkerArray

from accel_calibration.ros.markers import NEXT_ID, POSES_ID
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, rotation_with_up

pytestmark = pytest.mark.ros
START_NS = 1_700_000_000 * 10**9
# As a late RViz subscribes: the latest map at once (the node publishes it latched).
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def markers_of(array: MarkerArray, marker_id: int) -> Marker | None:
    return next((m for m in array.markers if m.action == Marker.ADD and m.id == marker_id), None)


def test_the_markers_show_the_poses_held_and_where_to_turn_next(tmp_path, tester, node_process):
    node_process(tmp_path / "cal.yaml")
    tester.wait_ready()
    received: list[MarkerArray] = []
    tester.node.create_subscription(MarkerArray, "calibration/markers", received.append, LATCHED)
    faces = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, -1]], dtype=float)
    errors = SensorErrors.mpu6050_like(np.random.default_rng(5), noise_mps2=0.02)
    imu = SyntheticImu(errors, [rotation_with_up(d) for d in faces], dwell_s=2.5, move_s=1.0, rate_hz=200.0, seed=5)
    tester.play(imu.samples(), start_ns=START_NS)

    def drawn_as_held():
        """The latest map has one point per pose /diagnostics says is held, every orientation played (the last
        one is still being held when the stream stops: counted and drawn as /calibrate would fit it)."""
        if not received or not tester.diagnostics:
            return False
        poses = markers_of(received[-1], POSES_ID)
        held = int(tester.diagnostics[-1]["poses"])
        return poses is not None and len(poses.points) == held == len(faces)

    assert tester.spin_until(drawn_as_held, 20.0), [len(a.markers) for a in received[-3:]]
    latest = received[-1]
    poses = markers_of(latest, POSES_ID)
    points = np.array([[p.x, p.y, p.z] for p in poses.points])
    # Each point is one played orientation, within a few degrees (no calibration in force: raw directions),
    # each orientation at most once.
    nearest = np.argmax(points @ faces.T, axis=1)
    assert len(set(nearest.tolist())) == len(points)
    assert np.all(np.degrees(np.arccos(np.clip(np.sum(points * faces[nearest], axis=1), -1, 1))) < 4.0)
    assert len(poses.colors) == len(points) and poses.header.frame_id == "imu_link"
    # The arrow points where the advice says: z never pointed up.
    assert tester.diagnostics[-1]["advice"] == "turn z up"
    arrow = markers_of(latest, NEXT_ID)
    assert arrow is not None and arrow.text == "turn z up"
    tip = np.array([arrow.points[1].x, arrow.points[1].y, arrow.points[1].z])
    np.testing.assert_allclose(tip / np.linalg.norm(tip), [0.0, 0.0, 1.0], atol=1e-9)
    # A reset drops the poses, and the map with them (DELETEALL first, then no points).
    assert tester.call("calibration/reset").success
    assert tester.spin_until(lambda: markers_of(received[-1], POSES_ID) is None, 10.0)
    assert received[-1].markers[0].action == Marker.DELETEALL


def _text_marker(array: MarkerArray) -> Marker | None:
    return next((m for m in array.markers if m.action == Marker.ADD and m.type == Marker.TEXT_VIEW_FACING), None)


def test_the_advice_is_a_text_marker_rviz_draws():
    """RViz draws no arrow's `text`: the advice is a TEXT_VIEW_FACING marker of its own, above the sphere."""
    from builtin_interfaces.msg import Time

    from accel_calibration.core.pose_map import pose_map
    from accel_calibration.core.session import CalibrationSession
    from accel_calibration.ros.markers import pose_markers

    session = CalibrationSession()
    progress = session.progress()
    array = pose_markers(pose_map(session, None, progress), "imu_link", Time())
    text = _text_marker(array)
    assert text is not None and text.text == progress.advice and progress.advice.startswith("turn")
    assert text.header.frame_id == "imu_link" and text.scale.z > 0 and text.color.a == 1.0
    assert text.pose.position.z > 1.0  # above the unit sphere, not inside it


def test_before_any_imu_the_markers_wait_for_data_and_point_nowhere(ros, tmp_path):
    """Finding: before any Imu arrived the arrow said "turn x up"."""
    from rclpy.parameter import Parameter

    from accel_calibration.ros.node import CalibrationNode
    from msg_tools.conversions import make_imu

    node = CalibrationNode(parameter_overrides=[Parameter("calibration_file", value=str(tmp_path / "cal.yaml"))])
    published: list[MarkerArray] = []
    node._markers.publish = published.append
    try:
        node._publish_diagnostics()
        waiting = published[-1]
        assert markers_of(waiting, NEXT_ID) is None
        assert _text_marker(waiting).text == "waiting for data on /imu/data_raw: no Imu message yet"
        node._imu.take(make_imu(START_NS, [0.0, 0.0, 9.81], [0.0, 0.0, 0.0]))
        node._publish_diagnostics()
        heard = published[-1]
        assert markers_of(heard, NEXT_ID) is not None and _text_marker(heard).text.startswith("turn")
    finally:
        node.close()
        node.destroy_node()
