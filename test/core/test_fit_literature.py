"""The fit against numbers nobody here chose: published tables and another project's result."""
import csv
import json
from collections import defaultdict

import numpy as np
from numpy.testing import assert_allclose

from accel_calibration import fit

G = 9.80665


def _song_qin(shared):
    rows = list(csv.DictReader(open(shared("literature/six_position_song_qin_2009.csv"))))
    accel_g = np.array([[float(r[k]) for k in ("ax", "ay", "az")] for r in rows])
    reference = np.array([[float(r[k]) for k in ("ref_x", "ref_y", "ref_z")] for r in rows])
    return accel_g, reference


def test_reference15_reproduces_song_qin_2009_coefficients(shared):
    accel_g, reference = _song_qin(shared)
    result = fit(accel_g * G, model="reference15", reference=reference, gravity=G)
    assert result.success, result.message
    cal = result.calibration
    # Back to the paper's forward model in g: A = a0 + S a + K3 a^2.
    a0 = cal.bias / G
    forward = np.linalg.inv(cal.matrix)
    k3 = cal.quadratic * G
    # Table from ../shared/data/literature/README.md (eq. 5 of the paper).
    published = {
        # axis: (a0, S, K1, K2, K3), K1/K2 = the other two axes in order
        0: (-0.0007860575, 0.99647219, -0.00731765, 0.008047535, 0.0007860475),
        1: (0.00048787685, 1.002959754, -0.0004409654, -0.0000844371, -0.00043663085),
        2: (0.00145661025, 1.00080185, -0.000595885, 0.0024119185, -0.00145873325),
    }
    for axis, (p_a0, p_s, p_k1, p_k2, p_k3) in published.items():
        others = [k for k in range(3) if k != axis]
        got = (a0[axis], forward[axis, axis], forward[axis, others[0]], forward[axis, others[1]], k3[axis])
        # The printed digits: 7-10 significant figures, i.e. absolute agreement to 5e-10 g or better
        # (least squares on this symmetric design is algebraically the paper's closed form).
        assert_allclose(got, (p_a0, p_s, p_k1, p_k2, p_k3), rtol=0, atol=5e-10, err_msg=f"axis {'xyz'[axis]}")


def _imucal_faces(shared):
    sums = defaultdict(list)
    with open(shared("real/imucal/annotated_session.csv")) as f:
        for row in csv.DictReader(f):
            sums[row["part"]].append([float(row["acc_x"]), float(row["acc_y"]), float(row["acc_z"])])
    faces = {"x_p": (1, 0, 0), "x_a": (-1, 0, 0), "y_p": (0, 1, 0), "y_a": (0, -1, 0), "z_p": (0, 0, 1),
             "z_a": (0, 0, -1)}
    means = np.array([np.mean(sums[name], axis=0) for name in faces])
    return means, np.array(list(faces.values()), dtype=float), list(faces)


def test_reference12_agrees_with_imucal_ferraris_on_the_six_faces(shared):
    means_counts, reference, names = _imucal_faces(shared)
    ref = json.load(open(shared("real/imucal/example_cal_reference.json")))
    k_a, r_a, b_a = (np.array(ref[k]) for k in ("K_a", "R_a", "b_a"))
    imucal_matrix = np.linalg.inv(r_a) @ np.linalg.inv(k_a)  # a = R^-1 K^-1 (raw - b)

    # imucal's Ferraris uses g = 9.81; the raw data are counts, the output m/s^2.
    result = fit(means_counts, model="reference12", reference=reference, gravity=9.81)
    assert result.success, result.message
    cal = result.calibration

    # M: both are exact functions of the face differences (U_p - U_n) / 2g on this orthogonal design,
    # so they agree to rounding.
    assert_allclose(cal.matrix, imucal_matrix, rtol=1e-9, atol=0)

    # b: Ferraris takes each axis' bias from the two faces along that axis only (its eq. 20),
    # least squares averages the axis over all six faces, which is less noisy. Check that
    # explanation exactly, and that the two differ by under 10 counts (~5 mg at ~2050 counts/g).
    index = {n: i for i, n in enumerate(names)}
    ferraris_bias = [(means_counts[index[f"{a}_p"], k] + means_counts[index[f"{a}_a"], k]) / 2
                     for k, a in enumerate("xyz")]
    assert_allclose(ferraris_bias, b_a, rtol=0, atol=1e-9)
    assert_allclose(cal.bias, means_counts.mean(axis=0), rtol=0, atol=1e-9)
    assert np.max(np.abs(cal.bias - b_a)) < 10.0
    # In physical terms the two calibrations agree within 5 mg on every face.
    difference_mg = np.abs(cal.apply(means_counts) - (means_counts - b_a) @ imucal_matrix.T) / (G * 1e-3)
    assert difference_mg.max() < 5.0
