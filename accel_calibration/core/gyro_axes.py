"""Does the gyro read in the accelerometer's axes and in rad/s? Checked before the gyro fit iterates.

A gyro whose axes are negated, swapped or turned against the accelerometer's (a board rotation, a driver's
frame mistake) or that gives deg/s as rad/s sends the gyro fit far from its identity start: it wanders its
iterations and ends "did not converge", or converges to a mirrored matrix. Instead: the rotation the gyro
integrates over each motion is compared with the turn between the poses' gravity directions for every
signed permutation of the axes (48) and the factors 1 and 57.3 either way; when one of them carries the
directions far better than the gyro as given, the gyro is not fitted and the mapping is named.

Cheap: for a proper signed permutation Q, integrating Q w gives Q R Q^T exactly (the coning term too,
cof(Q) = Q), and -Q w is Q (-w); so one integration per sign and factor (6) serves all 48 maps.
"""
from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np

from .gyro_scoring import GyroSamples, motion_rotations
from .pose import Pose
from .units import AXES

# (factor the raw rate is multiplied by, what it means when it is the one that fits)
UNIT_FACTORS = ((1.0, ""), (math.pi / 180.0, "gyro in deg/s given as rad/s"),
                (180.0 / math.pi, "gyro in rad/s given as deg/s"))
AS_GIVEN_FLOOR_MRAD = 100.0  # below this rms the gyro as given is nowhere near a wrong map: never flagged
BETTER_BY = 3.0  # a map is named only when it misses the poses this many times less than the gyro as given
MOST_MOTIONS = 12  # the first usable motions are enough to tell, and keep the check a fraction of the fit


def _proper_signed_permutations() -> np.ndarray:
    maps = []
    for order in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            matrix = np.zeros((3, 3))
            matrix[range(3), order] = signs
            if np.linalg.det(matrix) > 0:
                maps.append(matrix)
    identity_first = sorted(maps, key=lambda m: not np.array_equal(m, np.eye(3)))
    return np.array(identity_first)


PROPER_MAPS = _proper_signed_permutations()  # (24, 3, 3), the identity first


def describe_map(matrix: np.ndarray) -> str:
    """What w_true = matrix w_raw says about the raw axes, in the accelerometer's: '' for the identity."""
    if np.array_equal(matrix, np.eye(3)):
        return ""
    if np.array_equal(np.abs(matrix), np.eye(3)):
        negated = [AXES[i] for i in range(3) if matrix[i, i] < 0]
        return "gyro axes look negated against the accelerometer's: " + ", ".join(f"{a}→−{a}" for a in negated)
    target = [int(np.flatnonzero(matrix[:, j])[0]) for j in range(3)]  # raw axis j reads accel axis target[j]
    sign = [matrix[target[j], j] for j in range(3)]
    moved = [j for j in range(3) if target[j] != j]
    if len(moved) == 2 and all(s > 0 for s in sign):
        return f"gyro axes look swapped against the accelerometer's: {AXES[moved[0]]}↔{AXES[moved[1]]}"
    return "gyro axes look turned against the accelerometer's: " + ", ".join(
        f"{AXES[j]}→{'' if sign[j] > 0 else '−'}{AXES[target[j]]}" for j in range(3))


def gyro_axes_problem(poses: Sequence[Pose], motions: Sequence[GyroSamples | None], directions: np.ndarray,
                      initial: np.ndarray) -> str | None:
    """One line naming what looks wrong with the gyro's axes or unit (against the accelerometer's, whose
    unit gravity `directions` per pose are given), with the figures; None when the gyro as given (its
    start `initial`) fits best or the motions cannot tell. motions[k] joins poses k and k + 1 (None: not
    to be used)."""
    kept = [k for k, motion in enumerate(motions) if motion is not None][:MOST_MOTIONS]
    if len(kept) < 3:
        return None
    chosen: list[GyroSamples | None] = [motions[k] if k in kept else None for k in range(len(motions))]
    index = np.array(kept)
    start, end = directions[index], directions[index + 1]
    def rms_mrad(matrix: np.ndarray, maps: np.ndarray) -> np.ndarray:
        """Per map Q: the rms miss of the rate Q matrix w, from one integration (Q R Q^T is its rotation)."""
        _, rotations = motion_rotations(poses, chosen, matrix)
        turned = np.einsum("qab,kcb,qdc,kd->qka", maps, rotations, maps, start)  # Q R^T Q^T u
        rms: np.ndarray = np.sqrt(np.mean(np.sum((turned - end) ** 2, axis=2), axis=1)) * 1e3
        return rms

    as_given = float(rms_mrad(initial, PROPER_MAPS[:1])[0])
    if as_given < AS_GIVEN_FLOOR_MRAD:
        return None  # the usual case, after one integration
    scores = []  # (rms mrad, factor index, sign, map index)
    for f, (factor, _) in enumerate(UNIT_FACTORS):
        for sign in (1.0, -1.0):
            scores += [(float(r), f, sign, q) for q, r in enumerate(rms_mrad(sign * factor * initial, PROPER_MAPS))]
    best, f, sign, q = min(scores)
    if best * BETTER_BY > as_given:
        return None
    what = [text for text in (describe_map(sign * PROPER_MAPS[q]), UNIT_FACTORS[f][1]) if text]
    return (f"{'; '.join(what)} (the motions between poses miss the next pose by {as_given:.0f} mrad rms as "
            f"given, by {best:.0f} mrad so read); fix the driver's axes or unit (or the board rotation); the gyro "
            "fit was not run")
