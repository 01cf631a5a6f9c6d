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

Per sample, everything is numpy arithmetic on contiguous (k, N) rows of components, written in place
where it can be: a gyro fit evaluates this over ~100k intervals 4 times, and each pass over such rows costs
about what its arithmetic does, each fresh array's memory about as much again.

Derivative: with R = prod exp(theta_j), a change d theta_j turns R into R exp([d phi]) with
    d phi = R^T sum_j P_{j+1} J_r(theta_j) d theta_j,
P_{j+1} the orientation after interval j and J_r the right Jacobian of SO(3): exact, not a
linearisation of the integration scheme.
"""
from __future__ import annotations

from functools import cached_property

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
    flat = np.ascontiguousarray(np.reshape(theta, (-1, 3)).T)
    result: np.ndarray = _exp_rows(flat, _squared_norms(flat)).T.reshape(*np.shape(theta)[:-1], 4)
    return result


def _squared_norms(rows: np.ndarray) -> np.ndarray:
    """x^2 + y^2 + z^2 of (3, N) component rows."""
    x, y, z = rows
    squared: np.ndarray = x * x
    squared += y * y
    squared += z * z
    return squared


def _series_applies(squared: np.ndarray) -> bool:
    """Whether every angle (|theta|^2 given) is small enough for the series of exp and J_r."""
    return bool(len(squared) and float(squared.max()) < _SERIES_SQUARED)


def _exp_rows(theta: np.ndarray, squared: np.ndarray) -> np.ndarray:
    """exp of (3, N) rotation vector rows (|theta|^2 given) as (4, N) quaternion rows [w, x, y, z]."""
    out = np.empty((4, theta.shape[1]))
    if _series_applies(squared):
        # cos(a/2) and sin(a/2)/a as series in a^2 (np.sin and np.cos cost ~30 multiplications each);
        # the first terms left out, a^10 / (4^5 10!) and a^10 / (2 4^5 11!), are below 1e-19 here.
        np.multiply(squared, 1 / 10321920, out=out[0])
        for coefficient in (-1 / 46080, 1 / 384, -1 / 8):
            out[0] += coefficient
            out[0] *= squared
        out[0] += 1.0
        factor = squared * (1 / 185794560)
        for coefficient in (-1 / 645120, 1 / 3840, -1 / 48):
            factor += coefficient
            factor *= squared
        factor += 0.5
    else:
        angle = np.sqrt(squared)
        half = 0.5 * angle
        # sin(a/2)/a, its series below _SMALL_ANGLE
        with np.errstate(invalid="ignore", divide="ignore"):
            factor = np.where(angle < _SMALL_ANGLE, 0.5 - squared / 48.0,
                              np.sin(half) / np.where(angle == 0, 1, angle))
        np.cos(half, out=out[0])
    np.multiply(theta, factor, out=out[1:])
    return out


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of quaternions (N, 4) (normalised by the formula itself)."""
    return np.ascontiguousarray(_matrix_rows(q).T).reshape(-1, 3, 3)


def _matrix_rows(q: np.ndarray) -> np.ndarray:
    """quaternion_to_matrix's entries as a (9, N) array, row i * 3 + j: each a contiguous row."""
    return _frame_rows(np.ascontiguousarray(q.T))


def _frame_rows(q: np.ndarray) -> np.ndarray:
    """_matrix_rows of (4, N) quaternion rows, each entry written into its row (no temporary per entry)."""
    w, x, y, z = q
    scale = w * w
    for component in (x, y, z):
        scale += component * component
    np.divide(2.0, scale, out=scale)
    sw, sx, sy, sz = scale * w, scale * x, scale * y, scale * z
    wx, wy, wz = sw * x, sw * y, sw * z
    xx, xy, xz = sx * x, sx * y, sx * z
    yy, yz, zz = sy * y, sy * z, sz * z
    out = np.empty((9, q.shape[1]))
    for row, (a, b) in ((0, (yy, zz)), (4, (xx, zz)), (8, (xx, yy))):  # 1 - (a + b)
        np.add(a, b, out=out[row])
        np.subtract(1.0, out[row], out=out[row])
    np.subtract(xy, wz, out=out[1])
    np.add(xz, wy, out=out[2])
    np.add(xy, wz, out=out[3])
    np.subtract(yz, wx, out=out[5])
    np.subtract(xz, wy, out=out[6])
    np.add(yz, wx, out=out[7])
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
    rows = np.ascontiguousarray(theta.T)
    return _jacobian_of_rows(rows, _squared_norms(rows))


def _jacobian_coefficients(squared: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """f1 = (1 - cos t) / t^2 and f2 = (t - sin t) / t^3 of |t|^2."""
    if _series_applies(squared):
        # Per sample the angle is small: the coefficients' series (next terms below 1e-16 relative).
        f1 = squared / 3628800
        for coefficient in (-1 / 40320, 1 / 720, -1 / 24):
            f1 += coefficient
            f1 *= squared
        f1 += 0.5
        f2 = squared / 39916800
        for coefficient in (-1 / 362880, 1 / 5040, -1 / 120):
            f2 += coefficient
            f2 *= squared
        f2 += 1 / 6
        return f1, f2
    angle = np.sqrt(squared)
    small = angle < _SMALL_ANGLE
    safe = np.where(small, 1.0, angle)
    f1 = np.where(small, 0.5 - squared / 24.0, (1.0 - np.cos(safe)) / (safe * safe))
    f2 = np.where(small, 1.0 / 6.0 - squared / 120.0, (safe - np.sin(safe)) / (safe * safe * safe))
    return f1, f2


def _jacobian_of_rows(theta: np.ndarray, squared: np.ndarray) -> np.ndarray:
    """_jacobian_rows of (3, N) rotation vector rows, |theta|^2 given."""
    f1, f2 = _jacobian_coefficients(squared)
    diagonal = f2 * squared
    np.subtract(1.0, diagonal, out=diagonal)
    fx, fy, fz = theta * f2  # rows of f2 t and f1 t
    gx, gy, gz = theta * f1
    x, y, z = theta
    out = np.empty((9, theta.shape[1]))
    for row, (f, t) in enumerate(((fx, x), (fx, y), (fx, z), (fy, x), (fy, y), (fy, z), (fz, x), (fz, y), (fz, z))):
        np.multiply(f, t, out=out[row])
    for row, g, sign in ((1, gz, 1), (2, gy, -1), (3, gz, -1), (5, gx, 1), (6, gy, 1), (7, gx, -1)):
        if sign > 0:
            out[row] += g
        else:
            out[row] -= g
    for row in (0, 4, 8):
        out[row] += diagonal
    return out


def cofactor(matrix: np.ndarray) -> np.ndarray:
    """cof(M) = det(M) M^-T, so that (M a) x (M b) = cof(M) (a x b)."""
    result: np.ndarray = 0.5 * np.einsum("bij,ckl,ik,jl->bc", LEVI_CIVITA, LEVI_CIVITA, matrix, matrix)
    return result


def cofactor_derivative(matrix: np.ndarray) -> np.ndarray:
    """d cof(M)_bc / d M_pq as a (3, 3, 3, 3) array [b, c, p, q]."""
    result: np.ndarray = np.einsum("bpj,cql,jl->bcpq", LEVI_CIVITA, LEVI_CIVITA, matrix)
    return result


_IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
# p (x) q: per component of the product, its terms (component of p, component of q, sign) in order.
_PRODUCT_TERMS = (((0, 0, 1), (1, 1, -1), (2, 2, -1), (3, 3, -1)),
                  ((0, 1, 1), (1, 0, 1), (2, 3, 1), (3, 2, -1)),
                  ((0, 2, 1), (1, 3, -1), (2, 0, 1), (3, 1, 1)),
                  ((0, 3, 1), (1, 2, 1), (2, 1, -1), (3, 0, 1)))
_BLOCK = 16  # positions per block: each level of the scan is this many numpy steps
# Up to this many quaternions a loop over Python floats (~1.5 us each) costs no more than a level of the
# scan (15 vectorised products and the fix-up, ~0.3 ms at any small count).
_SEQUENTIAL = 256


def _multiply_into(p: np.ndarray, q: np.ndarray, out: np.ndarray, scratch: np.ndarray) -> None:
    """out = p (x) q on component-first arrays (4, ...) (broadcast), out not overlapping p or q; scratch
    is shaped like one component of out. The terms are summed left to right, as quaternion_product does."""
    if out[0].size <= _FEW:
        _multiply_few_into(p, q, out)
        return
    ps, qs = tuple(p), tuple(q)
    for row, terms in zip(out, _PRODUCT_TERMS):
        (i, j, _), *rest = terms
        np.multiply(ps[i], qs[j], out=row)
        for i, j, sign in rest:
            np.multiply(ps[i], qs[j], out=scratch)
            (np.add if sign > 0 else np.subtract)(row, scratch, out=row)


# The product's terms gathered: [c, t] is the t-th term of component c; summed over t in order, a - b being
# a + (-b) exactly, _multiply_few_into's values are _multiply_into's to the bit.
_LEFT = np.array([[i for i, _, _ in terms] for terms in _PRODUCT_TERMS])
_RIGHT = np.array([[j for _, j, _ in terms] for terms in _PRODUCT_TERMS])
_SIGNS = np.array([[sign for _, _, sign in terms] for terms in _PRODUCT_TERMS], dtype=float)
_FEW = 1024  # up to this many products at once, 5 numpy calls on 16 terms beat 28 on 1


def _multiply_few_into(p: np.ndarray, q: np.ndarray, out: np.ndarray) -> None:
    terms = p[_LEFT] * q[_RIGHT]
    terms *= _SIGNS.reshape(4, 4, *[1] * (terms.ndim - 2))
    np.add.reduce(terms, axis=1, out=out)


def _sequential_prefix(quaternions: np.ndarray) -> np.ndarray:
    """Inclusive running products of a few (4, n) quaternion rows, one by one in Python floats."""
    rows = quaternions.T.tolist()
    w, x, y, z = rows[0]
    out = [rows[0]]
    for qw, qx, qy, qz in rows[1:]:
        w, x, y, z = (w * qw - x * qx - y * qy - z * qz, w * qx + x * qw + y * qz - z * qy,
                      w * qy - x * qz + y * qw + z * qx, w * qz + x * qy - y * qx + z * qw)
        out.append([w, x, y, z])
    return np.array(out).T


def _to_grid(quaternions: np.ndarray, blocks: int) -> np.ndarray:
    """(4, N) rows as (4, _BLOCK, blocks), [:, k, b] element b * _BLOCK + k (identity past N): position k of
    every block is one contiguous row."""
    count, full = quaternions.shape[1], quaternions.shape[1] // _BLOCK
    grid = np.empty((4, _BLOCK, blocks))
    by_block = grid.transpose(0, 2, 1)
    by_block[:, :full] = quaternions[:, :full * _BLOCK].reshape(4, full, _BLOCK)
    if full < blocks:
        by_block[:, full, :count - full * _BLOCK] = quaternions[:, full * _BLOCK:]
        by_block[:, full, count - full * _BLOCK:] = _IDENTITY[:, None]
    return grid


def _from_grid(grid: np.ndarray, count: int) -> np.ndarray:
    """_to_grid undone: (4, count) rows."""
    out = np.empty((4, count))
    full = count // _BLOCK
    by_block = grid.transpose(0, 2, 1)
    out[:, :full * _BLOCK].reshape(4, full, _BLOCK)[...] = by_block[:, :full]
    if full < grid.shape[2]:
        out[:, full * _BLOCK:] = by_block[:, full, :count - full * _BLOCK]
    return out


def _prefix_rows(quaternions: np.ndarray) -> np.ndarray:
    """Inclusive running products of (4, N) quaternion rows: a scan inside every block of 16 at once (one
    vectorised step per position), then the blocks' totals scanned the same way, then each block multiplied
    by the product of the blocks before it; a few hundred are multiplied one by one."""
    count = quaternions.shape[1]
    if count <= _SEQUENTIAL:
        return _sequential_prefix(quaternions) if count else quaternions.copy()
    blocks = -(-count // _BLOCK)
    grid = _to_grid(quaternions, blocks)
    running = np.empty_like(grid)
    running[:, 0] = grid[:, 0]
    scratch = np.empty(blocks)
    for k in range(1, _BLOCK):
        _multiply_into(running[:, k - 1], grid[:, k], running[:, k], scratch)
    before = _prefix_rows(running[:, -1])  # the product of each block and all before it
    # grid is free now: the whole running products go there.
    grid[:, :, 0] = running[:, :, 0]
    _multiply_into(before[:, None, :-1], running[:, :, 1:], grid[:, :, 1:], np.empty((_BLOCK, blocks - 1)))
    return _from_grid(grid, count)


def prefix_product(quaternions: np.ndarray) -> np.ndarray:
    """Inclusive running products q_0 (x) ... (x) q_i of (N, 4) quaternions, in blocks: 16 numpy steps per
    level, log16(N) levels, none per sample (see _prefix_rows)."""
    result: np.ndarray = _prefix_rows(np.ascontiguousarray(quaternions.T)).T
    return result


def conjugate(q: np.ndarray) -> np.ndarray:
    result: np.ndarray = q * np.array([1.0, -1.0, -1.0, -1.0])
    return result


def _frames_times_jacobians(f: np.ndarray, j: np.ndarray) -> np.ndarray:
    """frames @ jacobians for (9, N) rows of each (row i * 3 + j), as (9, N), row a * 3 + c: each entry's
    three products summed in the order matmul sums them, on contiguous rows (a stacked 3 x 3 matmul costs
    ~170 ns a matrix), into its rows through one scratch row."""
    out = np.empty_like(f)
    scratch = np.empty(f.shape[1])
    for a in range(3):
        for c in range(3):
            row = out[a * 3 + c]
            np.multiply(f[a * 3], j[c], out=row)
            for b in (1, 2):
                np.multiply(f[a * 3 + b], j[3 * b + c], out=scratch)
                row += scratch
    return out


def _cross_into(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> np.ndarray:
    """a x b of (3, N) rows into out, as np.cross forms it."""
    for row, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):
        np.multiply(a[i], b[j], out=out[row])
        out[row] -= a[j] * b[i]
    return out


_GROUP = 16384  # intervals per group of motions whose derivative rows are formed at once


def _motion_groups(counts: np.ndarray) -> list[tuple[int, int]]:
    """Motion index ranges [a, b) of about _GROUP intervals each (a longer motion alone)."""
    groups, start, size = [], 0, 0
    for k, count in enumerate(counts):
        size += int(count)
        if size >= _GROUP:
            groups.append((start, k + 1))
            start, size = k + 1, 0
    if start < len(counts):
        groups.append((start, len(counts)))
    return groups


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
        self._groups = _motion_groups(counts)
        self.dt_s = np.concatenate([np.diff(t).astype(float) * 1e-9 for t in stamps_ns])
        self.coning_weight = self.dt_s**2 / 12.0
        # Per interval as (3, N) rows: the raw rates (bias removed) at its start and end.
        self._start = np.concatenate([r[:-1].T for r in rates], axis=1)
        self._end = np.concatenate([r[1:].T for r in rates], axis=1)
        share = np.concatenate([0.5 * (f[:-1] + f[1:]) for f in later_share])  # per interval
        # All that d theta_j is linear in, one row per column (see rotations_and_derivatives): dt mean and the
        # coning cross product (the first six: what theta is of M and cof(M)), then the rows that do not
        # change with the parameters. Formed in place: fresh memory costs more here than the arithmetic.
        factors = np.empty((12, len(self.dt_s)))
        np.add(self._start, self._end, out=factors[0:3])
        factors[0:3] *= 0.5
        factors[0:3] *= self.dt_s
        _cross_into(self._start, self._end, factors[3:6])
        factors[3:6] *= self.coning_weight
        np.subtract(self._end, self._start, out=factors[6:9])
        factors[6:9] *= self.coning_weight
        factors[9] = self.dt_s
        np.multiply(self.dt_s, 1.0 - share, out=factors[10])
        np.multiply(self.dt_s, share, out=factors[11])
        self._factors = factors
        self._fixed_factors = factors[6:].T  # (N, 6)

    @cached_property
    def mean_rate(self) -> np.ndarray:
        """(N, 3) each interval's mean raw rate (bias removed)."""
        result: np.ndarray = (0.5 * (self._start + self._end)).T
        return result

    @cached_property
    def difference(self) -> np.ndarray:
        """(N, 3) end minus start rate of each interval."""
        result: np.ndarray = (self._end - self._start).T
        return result

    @cached_property
    def cross(self) -> np.ndarray:
        """(N, 3) start x end rate of each interval."""
        result: np.ndarray = _cross_into(self._start, self._end, np.empty_like(self._start)).T
        return result

    def turned_rad(self) -> np.ndarray:
        """Per raw axis, the sum over all intervals of |rate| dt (bias removed): how much the motions turned."""
        result: np.ndarray = np.abs(self._factors[0:3]).sum(axis=1)
        return result

    def _rates(self, bias_change: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean and cross product of each interval's rates with the bias change db taken off:
        (a - db) x (b - db) = a x b + (b - a) x db."""
        if not np.any(bias_change):
            return self.mean_rate, self.cross
        return self.mean_rate - bias_change, self.cross + self.difference @ skew(bias_change)

    def _factor_rows(self, bias_change: np.ndarray) -> np.ndarray:
        """The (12, N) factors for a bias change: only the first six rows change with it."""
        if not np.any(bias_change):
            return self._factors
        mean, cross = self._rates(bias_change)
        factors = self._factors.copy()
        np.multiply(mean.T, self.dt_s, out=factors[0:3])
        np.multiply(cross.T, self.coning_weight, out=factors[3:6])
        return factors

    @staticmethod
    def _theta_rows(matrix: np.ndarray, factors: np.ndarray) -> np.ndarray:
        """theta_j as (3, N) rows: M dt mean_j + cof(M) coning_weight (a x b)_j, one product."""
        result: np.ndarray = np.concatenate([matrix, cofactor(matrix)], axis=1) @ factors[:6]
        return result

    def rotation_vectors(self, matrix: np.ndarray, bias_change: np.ndarray) -> np.ndarray:
        """theta_j (N, 3) of the corrected rate M (w - db) with the coning term."""
        return self._theta_rows(matrix, self._factor_rows(bias_change)).T

    def _motion_rotations(self, running: np.ndarray) -> np.ndarray:
        """Each motion's rotation from the (4, N) running products: the one at its end relative to the one
        before its start."""
        before = running[:, self.first - 1].T.copy()
        before[self.first == 0] = _IDENTITY
        result: np.ndarray = quaternion_to_matrix(quaternion_product(conjugate(before), running[:, self.last].T))
        return result

    def _running(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Running products over all intervals (N, 4) (orientation after interval j relative to the first
        motion's start), and each motion's rotation."""
        rows = np.ascontiguousarray(theta.T)
        running = _prefix_rows(_exp_rows(rows, _squared_norms(rows)))
        return running.T, self._motion_rotations(running)

    def rotations(self, matrix: np.ndarray, bias_change: np.ndarray) -> np.ndarray:
        """Each motion's rotation R (motions, 3, 3) for the gyro matrix and a bias change."""
        theta = self._theta_rows(matrix, self._factor_rows(bias_change))
        return self._motion_rotations(_prefix_rows(_exp_rows(theta, _squared_norms(theta))))

    def _motion_sums(self, running: np.ndarray, theta: np.ndarray, squared: np.ndarray, factors: np.ndarray
                     ) -> list[np.ndarray]:
        """Per motion sum_j A_j f_j^T (9, 12): A_j = P_{j+1} J_r(theta_j) as a row of 9, f_j its factors. Formed
        for ~16k intervals of whole motions at a time: the ~60 rows that takes then stay in the cache, and
        their memory is used again rather than mapped afresh (which cost a quarter of the time)."""
        sums = []
        for a, b in self._groups:
            lo, hi = self.first[a], self.last[b - 1] + 1
            frames = _frame_rows(running[:, lo:hi])
            weights = _frames_times_jacobians(frames, _jacobian_of_rows(theta[:, lo:hi], squared[lo:hi]))
            sums += [weights[:, s - lo:e + 1 - lo] @ factors[:, s:e + 1].T
                     for s, e in zip(self.first[a:b], self.last[a:b])]
        return sums

    def rotations_and_derivatives(self, matrix: np.ndarray, bias_change: np.ndarray,
                                  with_bias: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """R per motion, d phi / d x (motions, 3, 9 or 12): x the gyro matrix row-major, then the bias
        change when `with_bias`; R(x + dx) = R exp([d phi / d x dx]) to first order. And d phi / d b
        (motions, 2, 3, 3) for an error in the earlier and in the later pose's bias (the coning term's
        share, a few ppm of it, left out): what the noise of the poses' gyro means does to the motion."""
        factors = self._factor_rows(bias_change)
        cof = cofactor(matrix)
        theta = self._theta_rows(matrix, factors)
        squared = _squared_norms(theta)
        running = _prefix_rows(_exp_rows(theta, squared))
        rotations = self._motion_rotations(running)
        # With the running products P from the first motion's start, d phi of motion k is
        # P_end^T sum_j P_{j+1} J_r(theta_j) d theta_j: A_j = P_{j+1} J_r(theta_j), contracted per motion
        # with what d theta_j is linear in: dt mean_j (by M), the coning cross product (by cof(M)),
        # the rates' difference and dt (by the bias change).
        sums = np.stack(self._motion_sums(running, theta, squared, factors))
        sums = sums.reshape(self.motions, 3, 3, 12)  # [k, a, b, column]
        d_matrix = sums[..., 0:3] + np.einsum("kabc,bcpq->kapq", sums[..., 3:6], cofactor_derivative(matrix))
        columns = [d_matrix.reshape(self.motions, 3, 9)]
        if with_bias:
            # d theta_j / d db = -dt M + coning_weight cof [w_{j+1} - w_j]x  (the raw rates' own difference)
            generators = skew(np.eye(3))  # generators[c] = [e_c]x
            d_bias = -sums[..., 9] @ matrix + np.einsum("kabc,bd,cde->kae", sums[..., 6:9], cof, generators)
            columns.append(d_bias)
        ends = np.transpose(_frame_rows(running[:, self.last]).T.reshape(-1, 3, 3), (0, 2, 1))
        d_phi: np.ndarray = ends @ np.concatenate(columns, axis=2)
        d_pose_bias = -np.stack([ends @ sums[..., 10], ends @ sums[..., 11]], axis=1) @ matrix
        return rotations, d_phi, d_pose_bias
