"""Warm-ups of one IMU from several logs pooled (core/warmup_pool): a cold morning and a warm afternoon give
one curve over their joint range, each with its own turn-on bias; another sensor's warm-up is left out and
named; two that disagree are refused, never averaged."""
from __future__ import annotations

import dataclasses

import numpy as np

from accel_calibration.core.units import MG
from accel_calibration.core.warmup import fit_warmup, warmup_calibration
from accel_calibration.core.warmup_pool import PoolMember, pool_warmups

from helpers.warmup_sessions import Heating, temperature_errors, two_imus, warmup_recording

MORNING = Heating(start_degc=0.0, end_degc=22.0, tau_s=200.0, minutes=9.0)  # 0..20.5 degC
AFTERNOON = Heating(start_degc=18.0, end_degc=47.0, tau_s=200.0, minutes=9.0)  # 18..45
TURN_ON = (np.array([4.0, -3.0, 2.5]) * MG, np.array([0.3, -0.2, 0.25]) * 1e-3)


def member(name, recording) -> PoolMember:
    alone = fit_warmup([recording])
    assert alone.fit is not None, alone.refusal
    return PoolMember(name, recording, alone.fit, None)


def stranger_of(truth):
    return dataclasses.replace(truth, accel_amplitude=-truth.accel_amplitude,
                               gyro_amplitude=truth.gyro_amplitude * np.array([1.0, -1.0, 0.5]))


def day(truth, seed: int):
    rng = np.random.default_rng(seed)
    morning = warmup_recording(truth, rng, MORNING, accel_turn_on=TURN_ON[0], gyro_turn_on=TURN_ON[1], rate_hz=50.0)
    afternoon = warmup_recording(truth, rng, AFTERNOON, accel_turn_on=-TURN_ON[0], gyro_turn_on=-TURN_ON[1],
                                 rate_hz=50.0)
    return [member("morning", morning), member("afternoon", afternoon)]


def test_a_cold_morning_and_a_warm_afternoon_pool_over_their_joint_range():
    """They meet at 18..20.5 degC, one at its slow end, one at its fast start: tied there, each with its own
    turn-on bias (accelerometer and gyro, opposite in the two), one curve over 0..45 degC."""
    for seed, truth in enumerate(two_imus(), start=60):
        pooled = pool_warmups(day(truth, seed), None, fit_warmup)
        fit = pooled.result.fit
        assert fit is not None and pooled.left_out == ()
        assert fit.range_degc[0] < 0.5 and fit.range_degc[1] > 44.5 and not fit.lag_seen
        accel_mg, gyro_mradps = temperature_errors(warmup_calibration(fit), truth, np.linspace(*fit.range_degc, 200))
        assert accel_mg <= 1.5 and gyro_mradps <= 0.3, (accel_mg, gyro_mradps)


def test_another_sensors_warm_up_is_left_out_and_named_not_averaged_in():
    truth = two_imus()[0]
    members = day(truth, 62)
    members.append(member("stranger", warmup_recording(stranger_of(truth), np.random.default_rng(63),
                                                       Heating(8.0, 38.0, tau_s=200.0, minutes=9.0), rate_hz=50.0)))
    pooled = pool_warmups(members, None, fit_warmup)
    assert pooled.used == (0, 1) and [i for i, _ in pooled.left_out] == [2]
    assert "its warm-up disagrees with the other logs' (accelerometer" in pooled.left_out[0][1]
    fit = pooled.result.fit
    assert fit is not None
    accel_mg, gyro_mradps = temperature_errors(warmup_calibration(fit), truth, np.linspace(*fit.range_degc, 200))
    assert accel_mg <= 1.5 and gyro_mradps <= 0.3


def test_two_warm_ups_that_disagree_are_refused_not_averaged():
    truth = two_imus()[1]
    rng = np.random.default_rng(64)
    members = [member("ours", warmup_recording(truth, rng, Heating(10.0, 40.0, tau_s=200.0, minutes=9.0),
                                               rate_hz=50.0)),
               member("theirs", warmup_recording(stranger_of(truth), rng, Heating(12.0, 42.0, tau_s=200.0,
                                                                                   minutes=9.0), rate_hz=50.0))]
    pooled = pool_warmups(members, None, fit_warmup)
    assert pooled.result.fit is None
    assert "the warm-ups of ours and theirs disagree beyond noise" in str(pooled.result.refusal)
