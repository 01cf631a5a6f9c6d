"""The worker's pacer (live/worker_pace.py): while a stream flows, the work runs in slices with pauses between,
so the stream's processes get the cores back often; outside its block nothing of it is left."""
from __future__ import annotations

import multiprocessing
import signal
import threading
import time

import numpy as np
import pytest

from accel_calibration.live.worker_pace import Pacer

SLICE_S, PAUSE_S = 0.5e-3, 1e-3


@pytest.fixture
def pacer():
    pacer = Pacer(SLICE_S, PAUSE_S)
    yield pacer
    pacer.close()


def busy_stretches(seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """Python work for `seconds` of CPU: the stretches it ran without a break, and the breaks (s)."""
    marks = [time.perf_counter()]
    end = time.process_time() + seconds
    while time.process_time() < end:
        marks.append(time.perf_counter())
    steps = np.diff(marks)
    cuts = np.flatnonzero(steps > PAUSE_S / 2)
    edges = np.concatenate([[0], cuts + 1, [len(marks) - 1]])
    stretches = np.array([marks[b] - marks[a] for a, b in zip(edges[:-1], edges[1:] - 1, strict=True)])
    return stretches, steps[cuts]


def test_paced_work_runs_in_slices_with_pauses_between(pacer):
    assert pacer.available
    with pacer.paced():
        stretches, breaks = busy_stretches(0.06)
    # Unpaced, this is one 60 ms stretch. A loaded machine may cut a stretch shorter, never longer than a
    # slice by more than a scheduler's delay of the timer.
    assert np.median(stretches) <= 2 * SLICE_S
    assert np.max(stretches) < 5e-3
    assert pacer.pauses >= 10  # about 120 on an idle machine; fewer when others take the CPU meanwhile
    assert np.median(breaks) >= 0.9 * PAUSE_S
    assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)


def test_outside_its_block_and_when_off_the_work_runs_whole(pacer):
    with pacer.paced(on=False):
        busy_stretches(0.02)
    busy_stretches(0.02)
    assert pacer.pauses == 0
    assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)


def test_an_error_in_the_block_leaves_no_timer_armed(pacer):
    with pytest.raises(ZeroDivisionError), pacer.paced():
        busy_stretches(0.005)
        1 / 0  # noqa: B018
    taken = pacer.pauses
    busy_stretches(0.01)
    assert pacer.pauses == taken and signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)


def test_system_calls_in_slices_carry_on(pacer):
    """The worker sends on a pipe, sleeps and writes files while paced: a signal landing in a system call
    must not cut it short."""
    ours, theirs = multiprocessing.Pipe()
    payload = bytes(range(256)) * 4096  # 1 MiB: many writes, each a chance for the timer
    received = []
    reader = threading.Thread(target=lambda: received.append(theirs.recv_bytes()))
    reader.start()
    with pacer.paced():
        ours.send_bytes(payload)
        start = time.monotonic()
        time.sleep(0.02)
        slept = time.monotonic() - start
        busy_stretches(0.01)
    reader.join(timeout=10)
    assert received == [payload]
    assert slept >= 0.02
    assert pacer.pauses > 0


def test_nested_blocks_keep_one_timer(pacer):
    with pacer.paced():
        with pacer.paced():
            busy_stretches(0.01)
        busy_stretches(0.01)  # still paced: the outer block has not ended
        inner_and_after = pacer.pauses
    assert inner_and_after >= 4
    assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)


def test_away_from_the_main_thread_the_work_runs_whole():
    outcome = {}

    def work():
        pacer = Pacer(SLICE_S, PAUSE_S)
        with pacer.paced():
            stretches, _ = busy_stretches(0.01)
        outcome.update(available=pacer.available, pauses=pacer.pauses)
        pacer.close()

    thread = threading.Thread(target=work)
    thread.start()
    thread.join(timeout=10)
    assert outcome == {"available": False, "pauses": 0}


def test_close_gives_the_signal_back():
    before = signal.getsignal(signal.SIGALRM)
    pacer = Pacer(SLICE_S, PAUSE_S)
    assert signal.getsignal(signal.SIGALRM) != before
    pacer.close()
    assert signal.getsignal(signal.SIGALRM) == before
