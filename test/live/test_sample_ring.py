"""The sample ring: every record pushed is taken once, in order, whole; a reader that falls a whole ring
behind loses the oldest and counts them; across processes (the node's worker) the same."""
from __future__ import annotations

import multiprocessing

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from accel_calibration.live.sample_ring import SampleRing


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
    while not ring.flush():  # the last few, if the reader held the head at the last pushes
        pass
    stamps, values, lost = receiving.recv()
    worker.join(timeout=30)
    assert lost == 0 and worker.exitcode == 0
    np.testing.assert_array_equal(stamps, 10**18 + np.arange(count) * 1_000_000)
    np.testing.assert_array_equal(values[:, 0], np.arange(count))


def test_the_writer_never_waits_for_a_reader_that_holds_the_head_and_shows_its_records_later():
    """A reader in another process may be descheduled while it reads the head: the stream must not wait."""
    ring = SampleRing(6, capacity=1 << 12)  # the writer may run 64 records ahead of the head it shows
    ring.push(*record(0))
    assert len(ring.take().stamps_ns) == 1
    with ring._lock:  # the reader, caught inside its read of the head
        for i in range(1, 11):
            ring.push(*record(i))  # returns at once: held, the head is left to a later push
    assert len(ring.take().stamps_ns) == 0
    assert ring.flush()
    take = ring.take()
    np.testing.assert_array_equal(take.stamps_ns, 10**18 + np.arange(1, 11) * 1_000_000)
    assert take.lost == 0


def test_a_writer_ahead_by_its_whole_slack_waits_for_the_head_after_all():
    import threading

    ring = SampleRing(6, capacity=1 << 12)
    ring._lock.acquire()
    for i in range(64):
        ring.push(*record(i))
    pushed = threading.Event()
    writer = threading.Thread(target=lambda: (ring.push(*record(64)), pushed.set()))
    writer.start()
    assert not pushed.wait(0.2)  # a 65th record unseen: it waits, so the reader can count what it loses
    ring._lock.release()
    assert pushed.wait(10)
    writer.join()
    assert len(ring.take().stamps_ns) == 65


@settings(max_examples=100, deadline=None)
@given(bursts=st.lists(st.tuples(st.integers(0, 300), st.booleans()), max_size=30))
def test_records_pushed_while_the_reader_holds_the_head_are_lost_only_when_counted(bursts):
    """A ring just above the slack's size, written while its reader holds the head: a record is taken
    whole, in order, or counted lost, never half-read."""
    capacity = 64 * 64
    ring = SampleRing(6, capacity=capacity)
    pushed = taken = lost = 0
    for burst, held in bursts:
        if held:
            ring._lock.acquire()
        for _ in range(burst):
            if held and pushed - ring._published + 1 > ring._slack:
                break  # the next push would wait for the head (the test above)
            ring.push(*record(pushed))
            pushed += 1
        if held:
            ring._lock.release()
        take = ring.take()
        lost += take.lost
        first = taken + lost
        indices = np.arange(first, first + len(take.stamps_ns))
        np.testing.assert_array_equal(take.stamps_ns, 10**18 + indices * 1_000_000)
        np.testing.assert_array_equal(take.values[:, 5], indices + 5 / 8)
        taken += len(take.stamps_ns)
    ring.flush()
    final = ring.take()
    assert taken + lost + final.lost + len(final.stamps_ns) == pushed
