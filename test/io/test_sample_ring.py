"""The sample ring: every record pushed is taken once, in order, whole; a reader that falls a whole ring
behind loses the oldest and counts them; across processes (the node's worker) the same."""
from __future__ import annotations

import multiprocessing

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from accel_calibration.io.sample_ring import SampleRing


def record(i: int) -> tuple:
    return (10**18 + i * 1_000_000, *(float(i) + k / 8 for k in range(6)), i % 3 != 0)


@settings(max_examples=200, deadline=None)
@given(capacity=st.integers(1, 64), bursts=st.lists(st.integers(0, 200), max_size=30))
def test_every_record_is_taken_once_in_order_or_counted_lost(capacity, bursts):
    ring = SampleRing(6, capacity=capacity)
    pushed = taken = lost = 0
    for burst in bursts:
        for _ in range(burst):
            ring.push(*record(pushed))
            pushed += 1
        take = ring.take()
        expected_lost = max(0, pushed - taken - lost - capacity)
        assert take.lost == expected_lost
        lost += take.lost
        first = taken + lost
        indices = np.arange(first, first + len(take.stamps_ns))
        np.testing.assert_array_equal(take.stamps_ns, 10**18 + indices * 1_000_000)
        np.testing.assert_array_equal(take.values[:, 5], indices + 5 / 8)
        np.testing.assert_array_equal(take.flags, indices % 3 != 0)
        taken += len(take.stamps_ns)
    assert taken + lost + len(ring.take().stamps_ns) == pushed


def _read_in_a_worker(shared, count, out):
    ring = SampleRing.attach(shared)
    got = []
    while sum(len(t.stamps_ns) + t.lost for t in got) < count:
        got.append(ring.take())
    out.send((np.concatenate([t.stamps_ns for t in got]), np.concatenate([t.values for t in got]),
              sum(t.lost for t in got)))


def test_a_worker_process_reads_what_this_one_pushes_while_it_pushes():
    context = multiprocessing.get_context("spawn")
    ring = SampleRing(6, capacity=1 << 16, context=context)
    count = 50_000
    for i in range(1000):  # pushed before the worker attaches: it still takes them
        ring.push(*record(i))
    receiving, sending = context.Pipe(duplex=False)
    worker = context.Process(target=_read_in_a_worker, args=(ring.shareable(), count, sending))
    worker.start()
    for i in range(1000, count):
        ring.push(*record(i))
    stamps, values, lost = receiving.recv()
    worker.join(timeout=30)
    assert lost == 0 and worker.exitcode == 0
    np.testing.assert_array_equal(stamps, 10**18 + np.arange(count) * 1_000_000)
    np.testing.assert_array_equal(values[:, 0], np.arange(count))
