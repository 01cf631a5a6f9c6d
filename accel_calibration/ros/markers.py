"""The pose map (core/pose_map.py) as visualization_msgs/MarkerArray for RViz and Foxglove: a faint unit
sphere, the poses held as points on it coloured by status, the orientation to turn to next as an arrow
from the centre, the advice as text above the sphere (RViz draws no arrow's `text`), and the holes in
coverage as small grey points. Each array starts with DELETEALL, so a reset or a dropped pose leaves nothing
stale behind. The node publishes them latched (Transient Local): RViz sees them only with that durability."""
from __future__ import annotations

from collections.abc import Iterable

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from ..core.pose_map import PoseMap, PoseStatus

NAMESPACE = "accel_calibration"
# Colours by status (RGBA): green used, blue merged, red outlier; the next turn orange; holes grey.
STATUS_COLOURS = {PoseStatus.USED: (0.1, 0.8, 0.2, 1.0), PoseStatus.MERGED: (0.2, 0.4, 1.0, 1.0),
                  PoseStatus.OUTLIER: (0.9, 0.1, 0.1, 1.0)}
NEXT_COLOUR = (1.0, 0.6, 0.0, 1.0)
HOLE_COLOUR = (0.6, 0.6, 0.6, 0.8)
TEXT_COLOUR = (1.0, 1.0, 1.0, 1.0)
TEXT_HEIGHT_M, TEXT_ABOVE_M = 0.12, 1.5
SPHERE_COLOUR = (0.8, 0.8, 0.8, 0.15)
POSE_SIZE_M, HOLE_SIZE_M = 0.08, 0.04  # the sphere has radius 1 (m in RViz: scale the view, not the data)
# Marker ids within the namespace: the array is rebuilt whole each time.
SPHERE_ID, POSES_ID, NEXT_ID, HOLES_ID, ADVICE_ID = 0, 1, 2, 3, 4


def _colour(rgba: tuple[float, float, float, float]) -> ColorRGBA:
    return ColorRGBA(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _points(directions: Iterable[np.ndarray]) -> list[Point]:
    return [Point(x=float(d[0]), y=float(d[1]), z=float(d[2])) for d in directions]


def _marker(kind: int, marker_id: int, frame_id: str, stamp: Time, size: float) -> Marker:
    marker = Marker(type=kind, id=marker_id, ns=NAMESPACE, action=Marker.ADD)
    marker.header.frame_id = frame_id
    marker.header.stamp = stamp
    marker.pose.orientation.w = 1.0
    marker.scale.x = marker.scale.y = marker.scale.z = size
    return marker


def pose_markers(pose_map: PoseMap, frame_id: str, stamp: Time) -> MarkerArray:
    """The map as markers in `frame_id` (the IMU's frame: the sphere is drawn at the sensor)."""
    clear = Marker(action=Marker.DELETEALL, ns=NAMESPACE)
    clear.header.frame_id = frame_id
    markers = [clear]
    sphere = _marker(Marker.SPHERE, SPHERE_ID, frame_id, stamp, 2.0)
    sphere.color = _colour(SPHERE_COLOUR)
    markers.append(sphere)
    if len(pose_map.directions):
        poses = _marker(Marker.SPHERE_LIST, POSES_ID, frame_id, stamp, POSE_SIZE_M)
        poses.points = _points(pose_map.directions)
        poses.colors = [_colour(STATUS_COLOURS[status]) for status in pose_map.statuses]
        markers.append(poses)
    if pose_map.next_direction is not None:
        arrow = _marker(Marker.ARROW, NEXT_ID, frame_id, stamp, 0.0)
        arrow.points = _points([np.zeros(3), 1.3 * pose_map.next_direction])
        arrow.scale.x, arrow.scale.y, arrow.scale.z = 0.04, 0.08, 0.1  # shaft and head diameters, head length
        arrow.color = _colour(NEXT_COLOUR)
        arrow.text = pose_map.advice
        markers.append(arrow)
    if pose_map.advice:
        text = _marker(Marker.TEXT_VIEW_FACING, ADVICE_ID, frame_id, stamp, TEXT_HEIGHT_M)
        text.pose.position.z = TEXT_ABOVE_M
        text.color = _colour(TEXT_COLOUR)
        text.text = pose_map.advice
        markers.append(text)
    if len(pose_map.holes):
        hole_points = _marker(Marker.SPHERE_LIST, HOLES_ID, frame_id, stamp, HOLE_SIZE_M)
        hole_points.points = _points(pose_map.holes)
        hole_points.color = _colour(HOLE_COLOUR)
        markers.append(hole_points)
    return MarkerArray(markers=markers)
