"""The poses a session holds as a map on the unit sphere: where gravity was seen from (each pose's
specific-force direction), what became of each pose (used by the fit, merged with later ones, left out as
an outlier), the orientation to turn to next, and the orientations no pose comes near (the holes).

What the node draws on `calibration/markers` and the report's sphere, from one place. Directions are unit
vectors of the specific force (it points up) in the sensor frame, corrected by the calibration in force
when there is one.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .coverage import CANDIDATE_DIRECTIONS

if TYPE_CHECKING:
    from .calibration import Calibration
    from .session import CalibrationSession, Progress

# A candidate orientation (6 faces, 12 edges, 8 corners: 35-45 deg apart) with no pose within this angle
# is a hole: half the spacing, so a pose covers the candidate it is nearest to and no other.
HOLE_ANGLE_DEG = 22.5


class PoseStatus(enum.Enum):
    USED = "used"  # fitted as it was found
    MERGED = "merged"  # fitted, with later poses at its orientation merged into it
    OUTLIER = "outlier"  # left out by the last fit
    DROPPED = "dropped"  # given up by the store at capacity (replay)
    NOT_FITTED = "not fitted"  # no fit was run: too few poses, wrong units (replay)


@dataclass(frozen=True)
class PoseMap:
    directions: np.ndarray  # (N, 3) unit specific force of each pose held, in the store's order
    statuses: tuple[PoseStatus, ...]
    next_direction: np.ndarray | None  # (3,) the orientation advised next; None when nothing is missing
    advice: str  # the same, said: "turn z down"
    holes: np.ndarray  # (K, 3) candidate orientations no pose comes near


def holes(directions: np.ndarray, hole_angle_deg: float = HOLE_ANGLE_DEG) -> np.ndarray:
    """The candidate orientations (coverage.CANDIDATE_DIRECTIONS) farther than `hole_angle_deg` from every
    direction given."""
    if len(directions) == 0:
        return CANDIDATE_DIRECTIONS.copy()
    nearest = np.max(CANDIDATE_DIRECTIONS @ np.asarray(directions, dtype=float).T, axis=1)
    result: np.ndarray = CANDIDATE_DIRECTIONS[nearest < np.cos(np.radians(hole_angle_deg))]
    return result


def pose_map(session: CalibrationSession, calibration: Calibration | None, progress: Progress) -> PoseMap:
    """The map of `session`'s poses; `calibration` (the one in force) corrects their directions, `progress`
    is the session's progress with that calibration (its advice becomes the arrow)."""
    directions = session.directions(calibration)
    last_fit = session.last_fit
    outliers = set(last_fit.outlier_indices) if last_fit is not None else set()
    statuses = tuple(PoseStatus.OUTLIER if index in outliers else PoseStatus.MERGED if merges else PoseStatus.USED
                     for index, merges in enumerate(session.store.merges))
    advised = None if progress.advised_direction is None else np.array(progress.advised_direction)
    return PoseMap(directions, statuses, advised, progress.advice, holes(directions))
