"""Calibration history rows as the fleet writes them, and the properties every history backend (SQLite,
PostgreSQL) must show: the round trip, and many processes writing one history at once."""
from __future__ import annotations

import math

import numpy as np

from accel_calibration.io.history import HistoryRecord, open_history

DAY_NS = 86_400 * 10**9
START_NS = 1_793_577_600 * 10**9  # 2026-11-02 00:00 UTC


def record(i=0, *, vehicle="uav07", sensor="imu0", bias=(0.3, -0.2, 0.1), bias_sigma=(1e-3,) * 3,
           scale=(1.01, 0.99, 1.0), scale_sigma=(1e-4,) * 3, start_ns=None, status="calibrated", **extra):
    matrix = np.diag(scale).ravel()
    matrix[3] = 0.004  # a misalignment entry: stored, not compared
    sigma = np.zeros(9)
    sigma[[0, 4, 8]] = scale_sigma
    values = dict(recording_id=f"id{i:04d}-{vehicle}-{sensor}", path=f"/fleet/{vehicle}/flight{i}", size_bytes=1000 + i,
                  vehicle=vehicle, vehicle_source="folder", sensor=sensor, status=status,
                  start_ns=START_NS + i * DAY_NS if start_ns is None else start_ns,
                  bias=None if bias is None else tuple(bias), bias_sigma=tuple(bias_sigma), matrix=tuple(matrix),
                  matrix_sigma=tuple(sigma),
                  residual_rms_mg=0.5, poses=14, model="sphere9")
    values.update(extra)
    return HistoryRecord(**values)


def assert_round_trip(target, **first_extra) -> list[HistoryRecord]:
    """Two records written, the first written again: its row is updated whole, not added; the rows come
    back as written, also after reopening. Returns the rows."""
    first = record(1, temperature_min_degc=21.5, temperature_max_degc=24.0, outliers=1, condition_number=math.nan,
                   **first_extra)
    with open_history(target) as history:
        assert history.write([first, record(2)]) == 2
        history.write([record(1, bias=(0.31, -0.2, 0.1), reason=None)])
        rows = history.records()
    assert [r.recording_id for r in rows] == [first.recording_id, record(2).recording_id]
    assert rows[0].bias == (0.31, -0.2, 0.1)  # updated, not added
    assert rows[0].matrix[0] == 1.01 and rows[0].matrix[3] == 0.004 and rows[0].outliers is None
    assert (rows[0].temperature_min_degc, rows[0].temperature_max_degc) == (None, None)  # updated whole
    assert rows[1].scale == (1.01, 0.99, 1.0) and rows[1].scale_sigma == (1e-4,) * 3
    with open_history(target) as history:  # reopened: the schema is there, nothing lost
        assert len(history.records()) == 2
        assert [r.recording_id for r in history.records(vehicle="uav07", sensor="imu0")] == [r.recording_id
                                                                                            for r in rows]
        assert history.records(vehicle="uav99") == []
    return rows


# Several processes writing one SQLite file at once. They are forked from one helper that imported the
# package once (an import per writer would cost seconds each on this machine; the writers are separate
# processes all the same, each with its own engine, opened after the fork).
WRITERS = """
import multiprocessing, random, sys
from accel_calibration.io.history import HistoryRecord, open_history

db, writers, rounds = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])


def write(writer, barrier):
    try:
        with open_history(db) as history:
            barrier.wait(timeout=60)  # every writer starts at once
            for k in range(rounds):
                # Overlapping keys between writers and rounds: each row is written by several at once,
                # in a batch whose order differs between writers (where row locks are taken one by one,
                # as on PostgreSQL, opposite orders would deadlock).
                rows = [HistoryRecord(recording_id=f"rec{n:02d}", path=f"/fleet/v/flight{n}", size_bytes=n,
                                      vehicle="v", vehicle_source="folder", sensor="s", status="calibrated",
                                      bias=(writer, k, n), matrix_sigma=(writer, 0, 0, 0, k, 0, 0, 0, n))
                        for n in range(k % 5, 20, 3)]
                random.Random(1000 * writer + k).shuffle(rows)
                history.write(rows)
    except BaseException:
        barrier.abort()  # the others stop waiting for this one
        raise


if __name__ == "__main__":
    context = multiprocessing.get_context("fork")
    barrier = context.Barrier(writers)
    processes = [context.Process(target=write, args=(w, barrier)) for w in range(1, writers + 1)]
    for process in processes:
        process.start()
    for process in processes:
        process.join(timeout=120)
        if process.is_alive():
            process.kill()
            process.join()
    print(" ".join(str(p.exitcode) for p in processes))
"""
