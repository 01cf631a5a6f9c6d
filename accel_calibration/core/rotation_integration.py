"""Rotations integrated from gyro samples, many motions at once, and their exact derivative.

Conventions (the same as imu_tk's, Tedaldi et al. ICRA 2014): quaternions are Hamilton, stored
[w, x, y, z]; rates are body-frame; the orientation q of the sensor relative to where a motion started
obeys dq/dt = q (x) (0, w) / 2, so R(q) maps a vector written in the sensor's frame at time t to the
frame it had at the start: v_start = R v_t. A vector fixed in the world (gravity) therefore reads
u_end = R^T u_start at the end of a motion.

Between two samples w_j (at t_j) and w_{j+1} the rate is taken as linear in time: the interval's
rotation vector is then, to third order in dt,
    theta_j = dt (w_j + w_{j+1}) / 2 + dt^2 / 12 (w_j x w_{j+1})      (the second term: coning)
and the motion's rotation is the product of exp(theta_j). The products are formed by one blocked
prefix scan over all motions at once (16 numpy steps per level of log16(N) levels, none per sample); a motion's
rotation is the running product at its end relative to the one before its start.

Derivative: with R = prod exp(theta_j), a change d theta_j turns R into R exp([d phi]) with
    d phi = R^T sum_j P_{j+1} J_r(theta_j) d theta_j,
P_{j+1} the orientation after interval j and J_r the right Jacobian of SO(3): exact, not a
linearisation of the integration scheme.
"""
from __future__ import annotations

import numpy as np

# Levi-Civita symbol: cross products and cofactors as tensor contractions.
LEVI_CIVITA = np.zeros((3, 3, 3))
LEVI_CIVITA[0, 1, 2] = LEVI_CIVITA[1, 2, 0] = LEVI_CIVITA[2, 0, 1] = 1.0
LEVI_CIVITA[0, 2, 1] = LEVI_CIVITA[2, 1, 0] = LEVI_CIVITA[1, 0, 2] = -1.0
# Small angles take the series of the Jacobian's coefficients (their closed forms lose digits there).
_SMALL_ANGLE = 1e-4
# Below this squared angle (0.1 rad, 5.7 deg per sample interval) the series to t^8 is exact in doubles:
# the first term left out, t^10 / 12!, is below 1e-19.
_SERIES_SQUARED = 0.01


def quaternion_product(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """p (x) q for (..., 4) arrays [w, x, y, z]."""
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    ], axis=-1)


def quaternion_exp(theta: np.ndarray) -> np.ndarray:
    """exp of rotation vectors (..., 3) as unit quaternions (..., 4)."""
    angle = np.sqrt(np.einsum("...i,...i->...", theta, theta))
    half = 0.5 * angle
    # sin(a/2)/a, its series below _SMALL_ANGLE
    with np.errstate(invalid="ignore", divide="ignore"):
        factor = np.where(angle < _SMALL_ANGLE, 0.5 - angle**2 / 48.0, np.sin(half) / np.where(angle == 0, 1, angle))
    return np.concatenate([np.cos(half)[..., None], theta * factor[..., None]], axis=-1)


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of quaternions (N, 4) (normalised by the formula itself)."""
    return np.ascontiguousarray(_matrix_rows(q).T).reshape(-1, 3, 3)


def _matrix_rows(q: np.ndarray) -> np.ndarray:
    """quaternion_to_matrix's entries as a (9, N) array, row i * 3 + j: each a contiguous row."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    s = 2.0 / (w * w + x * x + y * y + z * z)
    wx, wy, wz = s * w * x, s * w * y, s * w * z
    xx, xy, xz = s * x * x, s * x * y, s * x * z
    yy, yz, zz = s * y * y, s * y * z, s * z * z
    out = np.empty((9, len(q)))
    out[0], out[1], out[2] = 1.0 - (yy + zz), xy - wz, xz + wy
    out[3], out[4], out[5] = xy + wz, 1.0 - (xx + zz), yz - wx
    out[6], out[7], out[8] = xz - wy, yz + wx, 1.0 - (xx + yy)
    return out


def skew(v: np.ndarray) -> np.ndarray:
    """[v]x for (..., 3): skew(v) @ a == cross(v, a)."""
    zero = np.zeros(v.shape[:-1])
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)


def right_jacobian(theta: np.ndarray) -> np.ndarray:
    """J_r(theta) of SO(3) for (N, 3) rotation vectors, (N, 3, 3): exp(theta + d) = exp(theta) exp(J_r d) to
    first order. J_r = I - f1 [t]x + f2 [t]x^2 = (1 - f2 |t|^2) I - f1 [t]x + f2 t t^T."""
    return np.ascontiguousarray(_jacobian_rows(theta).T).reshape(-1, 3, 3)


def _jacobian_rows(theta: np.ndarray) -> np.ndarray:
    """right_jacobian's entries as a (9, N) array, row i * 3 + j."""
    x, y, z = theta[:, 0], theta[:, 1], theta[:, 2]
    squared = x * x + y * y + z * z
    if len(squared) and float(squared.max()) < _SERIES_SQUARED:
        # Per sample the angle is small: the coefficients' series (next terms below 1e-16 relative).
        f1 = 0.5 + squared * (-1 / 24 + squared * (1 / 720 + squared * (-1 / 40320 + squared / 3628800)))
        f2 = 1 / 6 + squared * (-1 / 120 + squared * (1 / 5040 + squared * (-1 / 362880 + squared / 39916800)))
    else:
        angle = np.sqrt(squared)
        small = angle < _SMALL_ANGLE
        safe = np.where(small, 1.0, angle)
        f1 = np.where(small, 0.5 - squared / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
        f2 = np.where(small, 1.0 / 6.0 - squared / 120.0, (safe - np.sin(safe)) / (safe * safe * safe))
    diagonal = 1.0 - f2 * squared
    fx, fy, fz = f2 * x, f2 * y, f2 * z
    gx, gy, gz = f1 * x, f1 * y, f1 * z
    out = np.empty((9, len(theta)))
    out[0], out[1], out[2] = diagonal + fx * x, fx * y + gz, fx * z - gy
    out[3], out[4], out[5] = fy * x - gz, diagonal + fy * y, fy * z + gx
    out[6], out[7], out[8] = fz * x + gy, fz * y - gx, diagonal + fz * z
    return out


def cofactor(matrix: np.ndarray) -> np.ndarray:
    """cof(M) = det(M) M^-T, so that (M a) x (M b) = cof(M) (a x b)."""
    result: np.ndarray = 0.5 * np.einsum("bij,ckl,ik,jl->bc", LEVI_CIVITA, LEVI_CIVITA, matrix, matrix)
    return result


def cofactor_derivative(matrix: np.ndarray) -> np.ndarray:
    """d cof(M)_bc / d M_pq as a (3, 3, 3, 3) array [b, c, p, q]."""
    result: np.ndarray = np.einsum("bpj,cql,jl->bcpq", LEVI_CIVITA, LEVI_CIVITA, matrix)
    return result


def _product_components(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """p (x) q on component-first arrays (4, ...): the four components of the product."""
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw)


_BLOCK = 16  # positions per block: each level of the scan is this many numpy steps


def _prefix_product_components(quaternions: np.ndarray) -> np.ndarray:
    """Inclusive running products of component-first quaternions (4, N)."""
    count = quaternions.shape[1]
    if count <= 1:
        return quaternions.copy()
    blocks = -(-count // _BLOCK)
    padded = np.empty((4, blocks * _BLOCK))
    padded[:, :count] = quaternions
    padded[:, count:] = np.array([[1.0], [0.0], [0.0], [0.0]])
    # grid[:, k, b] is element b * _BLOCK + k: position k of every block is one contiguous row.
    grid = np.ascontiguousarray(padded.reshape(4, blocks, _BLOCK).transpose(0, 2, 1))
    for k in range(1, _BLOCK):
        w, x, y, z = _product_components(grid[:, k - 1], grid[:, k])
        grid[0, k], grid[1, k], grid[2, k], grid[3, k] = w, x, y, z
    if blocks > 1:
        before = _prefix_product_components(grid[:, -1])  # the product of each block and all before it
        w, x, y, z = _product_components(before[:, None, :-1], grid[:, :, 1:])
        grid[0, :, 1:], grid[1, :, 1:], grid[2, :, 1:], grid[3, :, 1:] = w, x, y, z
    result: np.ndarray = grid.transpose(0, 2, 1).reshape(4, -1)[:, :count]
    return result


def prefix_product(quaternions: np.ndarray) -> np.ndarray:
    """Inclusive running products q_0 (x) ... (x) q_i of (N, 4) quaternions, in blocks: a scan inside every
    block of 16 at once (one vectorised step per position), then the blocks' totals scanned the same way,
    then each block multiplied by the product of the blocks before it: 16 numpy steps per level, log16(N)
    levels, none per sample."""
    result: np.ndarray = _prefix_product_components(np.ascontiguousarray(quaternions.T)).T
    return result


def conjugate(q: np.ndarray) -> np.ndarray:
    result: np.ndarray = q * np.array([1.0, -1.0, -1.0, -1.0])
    return result


def _frames_times_jacobians(f: np.ndarray, j: np.ndarray) -> np.ndarray:
    """frames @ jacobians for (9, N) rows of each (row i * 3 + j), as (9, N), row a * 3 + c: each entry's
    three products summed in the order matmul sums them, on contiguous rows (a stacked 3 x 3 matmul costs
    ~170 ns a matrix)."""
    out = np.empty_like(f)
    for a in range(3):
        for c in range(3):
            row = out[a * 3 + c]
            np.multiply(f[a * 3], j[c], out=row)
            row += f[a * 3 + 1] * j[3 + c]
            row += f[a * 3 + 2] * j[6 + c]
    return out


class IntervalSet:
    """The sample intervals of several motions, flattened: interval j joins sample j and j + 1 of its
    motion. Holds what does not depend on the gyro matrix: the bias-free raw rates' mean, cross product
    and difference per interval, and the durations."""

    def __init__(self, stamps_ns: list[np.ndarray], rates: list[np.ndarray], later_share: list[np.ndarray]):
        """stamps_ns, rates (bias removed) and later_share per motion, one per sample: how much of the later
        pose's bias (against the earlier's) the sample's bias was interpolated from (0 at the start, 1 at
        the end)."""
        counts = np.array([len(t) - 1 for t in stamps_ns])
        self.motions = len(counts)
        self.first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.intp)  # first interval per motion
        self.last = self.first + counts - 1
        self.dt_s = np.concatenate([np.diff(t).astype(float) * 1e-9 for t in stamps_ns])
        start = np.concatenate([r[:-1] for r in rates])  # (N, 3) raw, bias removed
        end = np.concatenate([r[1:] for r in rates])
        self.mean_rate = 0.5 * (start + end)
        self.difference = end - start
        self.cross = np.cross(start, end)
        self.coning_weight = self.dt_s**2 / 12.0
        share = np.concatenate([0.5 * (f[:-1] + f[1:]) for f in later_share])  # per interval
        # The columns of what d theta_j is linear in that do not change with the parameters (see below).
        self._fixed_factors = np.concatenate([self.coning_weight[:, None] * self.difference, self.dt_s[:, None],
                                              (self.dt_s * (1.0 - share))[:, None], (self.dt_s * share)[:, None]],
                                             axis=1)

    def _rates(self, bias_change: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and cross product of each interval's rates with the bias change db taken off:
        (a - db) x (b - db) = a x b + (b - a) x db."""
        if not np.any(bias_change):
            return self.mean_rate, self.cross
        return self.mean_rate - bias_change, self.cross + self.difference @ skew(bias_change)

    def rotation_vectors(self, matrix: np.ndarray, bias_change: np.ndarray) -> np.ndarray:
        """theta_j (N, 3) of the corrected rate M (w - db) with the coning term."""
        mean, cross = self._rates(bias_change)
        theta: np.ndarray = (self.dt_s[:, None] * (mean @ matrix.T)
                             + self.coning_weight[:, None] * (cross @ cofactor(matrix).T))
        return theta

    def _running(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Running products over all intervals (orientation after interval j relative to the first motion's
        start), and each motion's rotation: the running product at its end relative to its start."""
        running = prefix_product(quaternion_exp(theta))
        identity = np.array([[1.0, 0.0, 0.0, 0.0]])
        before = np.concatenate([identity, running])[self.first]  # the running product before each motion
        rotations: np.ndarray = quaternion_to_matrix(quaternion_product(conjugate(before), running[self.last]))
        return running, rotations

    def rotations(self, matrix: np.ndarray, bias_change: np.ndarray) -> np.ndarray:
        """Each motion's rotation R (motions, 3, 3) for the gyro matrix and a bias change."""
        return self._running(self.rotation_vectors(matrix, bias_change))[1]

    def rotations_and_derivatives(self, matrix: np.ndarray, bias_change: np.ndarray,
                                  with_bias: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """R per motion, d phi / d x (motions, 3, 9 or 12): x the gyro matrix row-major, then the bias
        change when `with_bias`; R(x + dx) = R exp([d phi / d x dx]) to first order. And d phi / d b
        (motions, 2, 3, 3) for an error in the earlier and in the later pose's bias (the coning term's
        share, a few ppm of it, left out): what the noise of the poses' gyro means does to the motion."""
        mean, cross = self._rates(bias_change)
        dt, coning_weight = self.dt_s, self.coning_weight
        cof = cofactor(matrix)
        theta = dt[:, None] * (mean @ matrix.T) + coning_weight[:, None] * (cross @ cof.T)
        running, rotations = self._running(theta)
        # With the running products P from the first motion's start, d phi of motion k is
        # P_end^T sum_j P_{j+1} J_r(theta_j) d theta_j: A_j = P_{j+1} J_r(theta_j), contracted per motion
        # with what d theta_j is linear in: dt mean_j (by M), the coning cross product (by cof(M)),
        # the rates' difference and dt (by the bias change).
        frames = _matrix_rows(running)  # (9, N)
        weights = _frames_times_jacobians(frames, _jacobian_rows(theta))  # (9, N): row a*3+b
        factors = np.concatenate([dt[:, None] * mean, coning_weight[:, None] * cross, self._fixed_factors],
                                 axis=1)  # (N, 12)
        sums = np.stack([weights[:, s:e + 1] @ factors[s:e + 1] for s, e in zip(self.first, self.last)])
        sums = sums.reshape(self.motions, 3, 3, 12)  # [k, a, b, column]
        d_matrix = sums[..., 0:3] + np.einsum("kabc,bcpq->kapq", sums[..., 3:6], cofactor_derivative(matrix))
        columns = [d_matrix.reshape(self.motions, 3, 9)]
        if with_bias:
            # d theta_j / d db = -dt M + coning_weight cof [w_{j+1} - w_j]x  (the raw rates' own difference)
            generators = skew(np.eye(3))  # generators[c] = [e_c]x
            d_bias = -sums[..., 9] @ matrix + np.einsum("kabc,bd,cde->kae", sums[..., 6:9], cof, generators)
            columns.append(d_bias)
        ends = np.transpose(frames[:, self.last].T.reshape(-1, 3, 3), (0, 2, 1))
        d_phi: np.ndarray = ends @ np.concatenate(columns, axis=2)
        d_pose_bias = -np.stack([ends @ sums[..., 10], ends @ sums[..., 11]], axis=1) @ matrix
        return rotations, d_phi, d_pose_bias
