"""How efficient is the fit when poses differ in length? Monte Carlo against the Cramér-Rao bound.

Each geometry: 24 random orientations, a random sphere9 truth (bias ~50 mg, M = I + lower-triangular
~5e-3), pose lengths uniform in 1..10 s, so each pose mean's noise is s_i = rate / sqrt(length) per axis
(--rate-mg, default 0.3 mg sqrt(s): ~3 mg of sample noise at 100 Hz). Each draw: fresh noise, the fit given the poses'
sigmas as a replay would estimate them (from 100 Hz samples), and optionally a common extra error per pose
(--extra-ug, e.g. 110 as on the imu_tk Xsens recording). Two fits per draw: unweighted (today's) and
weighted (w_i = 1 / (s_i^2 + tau^2), tau fitted).

Printed per fit: each parameter's Monte Carlo mean-square error over its Cramér-Rao bound (the inverse
Fisher information of the poses' true noise, at the truth), its mean over geometries and the worst
geometry; the pooled 1/2/3 sigma coverage of the reported sigmas against Student-t with n - 9 dof, and the
lowest 2 sigma coverage of any geometry and parameter. `--equal` gives every pose the same length.

    .venv/bin/python bench/bench_efficiency.py [--geometries 20] [--draws 500] [--extra-ug 0] [--equal]
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import t as student_t

from accel_calibration import fit
from accel_calibration.core.fit import OutlierOptions
from accel_calibration.core.models import SphereModel

G = 9.80665
MG = G * 1e-3
POSES = 24
RATE_MG_SQRT_S = 0.3  # per axis, over sqrt(seconds): the default of --rate-mg
SAMPLE_RATE_HZ = 100.0
NO_OUTLIERS = OutlierOptions(threshold_mg=0.0)
MODEL = SphereModel("sphere9")


def geometry(rng: np.random.Generator, equal: bool):
    directions = Rotation.random(POSES, random_state=rng).apply([0.0, 0.0, 1.0])
    matrix = np.eye(3) + np.tril(rng.normal(0.0, 5e-3, (3, 3)))
    bias = rng.normal(0.0, 50 * MG, 3)
    length_s = np.full(POSES, 5.5) if equal else rng.uniform(1.0, 10.0, POSES)
    return directions, matrix, bias, length_s


def cramer_rao(directions, matrix, bias, pose_variance):
    """Diagonal of the inverse Fisher information of sphere9's 9 parameters: the residual |M (a - b)| - g
    of pose i has variance v_i |M^T n_i|^2 for isotropic noise of variance v_i per axis of its mean."""
    raw = (G * directions) @ np.linalg.inv(matrix).T + bias
    p = MODEL.pack(bias, matrix)
    _, jacobian = MODEL.residual_and_jacobian(p, raw, G)
    corrected = (raw - bias) @ matrix.T
    normals = corrected / np.linalg.norm(corrected, axis=1)[:, None]
    residual_variance = pose_variance * np.sum((normals @ matrix) ** 2, axis=1)
    information = jacobian.T @ (jacobian / residual_variance[:, None])
    return p, np.diag(np.linalg.inv(information))


def reference_cramer_rao(directions, matrix, bias, pose_variance):
    """reference12 as fitted, forward a_raw = b + S g u per axis (S = M^-1): the parameters [b, S row-major]
    and the diagonal of the inverse Fisher information (each axis a linear model in [1, g u])."""
    design = np.column_stack([np.ones(len(directions)), G * directions])
    per_axis = np.diag(np.linalg.inv(design.T @ (design / pose_variance[:, None])))
    forward = np.linalg.inv(matrix)
    return np.concatenate([bias, forward.ravel()]), np.concatenate([[per_axis[0]] * 3, np.tile(per_axis[1:], 3)])


def estimate(model, calibration, sigma):
    """The parameters the bound is for, and their reported sigma (NaN where the fit reports none: S)."""
    if model == "sphere9":
        return MODEL.pack(calibration.bias, calibration.matrix), MODEL.pack(sigma.bias, sigma.matrix)
    return (np.concatenate([calibration.bias, np.linalg.inv(calibration.matrix).ravel()]),
            np.concatenate([sigma.bias, np.full(9, np.nan)]))


def run(geometries: int, draws: int, extra_ug: float, equal: bool, seed: int, rate_mg: float,
        model: str = "sphere9") -> None:
    rng = np.random.default_rng(seed)
    extra = extra_ug * 1e-6 * G
    dof = POSES - (MODEL.size if model == "sphere9" else 4)
    ratios = {"unweighted": [], "weighted": []}  # per geometry: (9,) MSE / CRB
    z = {"unweighted": [], "weighted": []}  # per geometry: (draws, 9) |error| / sigma
    taus = []
    started = time.perf_counter()
    for _ in range(geometries):
        directions, matrix, bias, length_s = geometry(rng, equal)
        sigma = rate_mg * MG / np.sqrt(length_s)
        bound_of = cramer_rao if model == "sphere9" else reference_cramer_rao
        truth, bound = bound_of(directions, matrix, bias, sigma**2 + extra**2)
        clean = (G * directions) @ np.linalg.inv(matrix).T + bias
        samples = np.round(length_s * SAMPLE_RATE_HZ).astype(int)
        errors = {name: [] for name in ratios}
        sigmas = {name: [] for name in ratios}
        for _ in range(draws):
            noisy = clean + rng.normal(0.0, 1.0, clean.shape) * np.sqrt(sigma**2 + extra**2)[:, None]
            # The sigma a replay would report: the samples' spread (3 axes, n - 1 dof each) over sqrt(n).
            estimated = sigma * np.sqrt(rng.chisquare(3 * (samples - 1)) / (3 * (samples - 1)))
            for name, given in (("unweighted", None), ("weighted", estimated)):
                result = fit(noisy, model=model, outlier_options=NO_OUTLIERS, pose_sigma_mps2=given,
                             reference=None if model == "sphere9" else directions)
                assert result.success, result.message
                value, reported = estimate(model, result.calibration, result.sigma)
                errors[name].append(value - truth)
                sigmas[name].append(reported)
                if name == "weighted":
                    taus.append(result.pose_extra_sigma or 0.0)
        for name in ratios:
            e, s = np.array(errors[name]), np.array(sigmas[name])
            ratios[name].append((e**2).mean(axis=0) / bound)
            z[name].append(np.abs(e) / s)
    elapsed = time.perf_counter() - started
    names = MODEL.parameter_names() if model == "sphere9" else (
        [f"b_{a}" for a in "xyz"] + [f"S_{a}{b}" for a in "xyz" for b in "xyz"])
    expected = [2 * student_t.cdf(k, dof) - 1 for k in (1, 2, 3)]
    print(f"{model}: {geometries} geometries x {draws} draws, {POSES} poses of "
          f"{'5.5 s each' if equal else '1-10 s'} ({rate_mg:g} mg sqrt(s) of noise), extra error {extra_ug:g} ug "
          f"per pose; {elapsed:.0f} s")
    print("MSE / Cramer-Rao bound per parameter (mean over geometries; worst geometry):")
    print("  " + " ".join(f"{n:>11s}" for n in ["fit", *names]))
    for name in ratios:
        r = np.array(ratios[name])
        print(f"  {name:>11s} " + " ".join(f"{v:11.3f}" for v in r.mean(axis=0)))
        print(f"  {'worst':>11s} " + " ".join(f"{v:11.3f}" for v in r.max(axis=0)))
    print(f"coverage of the reported sigma, pooled (Student-t, {dof} dof: "
          + " / ".join(f"{v:.3f}" for v in expected) + "):")
    for name in z:
        pooled = np.concatenate(z[name])
        reported = np.isfinite(pooled[0])  # reference12 reports sigma of M, not of S: b only
        pooled = pooled[:, reported]
        cover = [float((pooled <= k).mean()) for k in (1, 2, 3)]
        lowest = min(float((zz[:, j] <= 2).mean()) for zz in z[name] for j in np.flatnonzero(reported))
        print(f"  {name:>11s} 1/2/3 sigma " + " / ".join(f"{v:.3f}" for v in cover)
              + f"; lowest 2 sigma of any geometry and parameter {lowest:.3f}")
    taus = np.array(taus)
    print(f"tau fitted: median {np.median(taus) / MG * 1e3:.0f} ug, {np.mean(taus > 0):.0%} of the fits found one > 0")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--geometries", type=int, default=20)
    parser.add_argument("--draws", type=int, default=500)
    parser.add_argument("--extra-ug", type=float, default=0.0, help="common extra error per pose, ug per axis")
    parser.add_argument("--equal", action="store_true", help="every pose the same length")
    parser.add_argument("--rate-mg", type=float, default=RATE_MG_SQRT_S,
                        help="noise of a pose mean of 1 s, mg per axis (default 0.3; 0.05 gives the imu_tk Xsens "
                             "recording's 16-50 ug per pose)")
    parser.add_argument("--model", choices=("sphere9", "reference12"), default="sphere9",
                        help="reference12: the bound is for b and S = M^-1 (its linear parameters); coverage of b")
    parser.add_argument("--seed", type=int, default=22)
    args = parser.parse_args()
    run(args.geometries, args.draws, args.extra_ug, args.equal, args.seed, args.rate_mg, args.model)


if __name__ == "__main__":
    main()
