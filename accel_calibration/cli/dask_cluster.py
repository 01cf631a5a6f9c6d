"""The Dask plumbing of `fleet` and `replay --jobs`: a local cluster (workers forked from a fork server
with the replay already imported), a client of it or of an existing scheduler (one line when none
answers), and tasks run with their results yielded as they finish. Dask is imported only here, and only
when a command runs (the CLI starts fast)."""
from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from ..core.errors import AccelCalibrationError

# What each worker has imported before its first task: the replay of one recording (cli/replay.py,
# cli/fleet.py's calibrate_recording) and the readers.
FORK_SERVER_PRELOAD = ("accel_calibration.cli.replay", "accel_calibration.cli.fleet", "accel_calibration.bag.replay",
                       "accel_calibration.bag.recording", "accel_calibration.bag.corrected_copy")


class ClusterError(AccelCalibrationError):
    """cli: no Dask scheduler to run on (another scheme, nothing there, not a Dask scheduler); one line."""


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


@contextlib.contextmanager
def local_cluster(workers: int | None = None, **options: Any) -> Iterator[Any]:
    """A Dask LocalCluster of `workers` processes (default one per core), one thread each (replay is Python
    and numpy, bound by the GIL), its HTTP server on a free port (8787 may be another cluster's), quiet;
    closed with the block. Workers are forked from a
    fork server that has Dask imported once (Dask's own test suite does this): a cluster starts and stops
    seconds sooner than with fresh interpreters, which matters for `replay --jobs` of a few bags."""
    import logging
    import multiprocessing

    import dask
    from distributed import LocalCluster

    method = "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"
    with dask.config.set({"distributed.worker.multiprocessing-method": method}):
        if method == "forkserver":
            from distributed.utils import get_mp_context

            # Dask sets the fork server's imports once per process; ours join them, so each worker starts
            # with the replay (numpy, scipy, the readers) already imported. No effect once the server runs.
            get_mp_context().set_forkserver_preload(["distributed", *FORK_SERVER_PRELOAD])
        # The dashboard (no authentication) on the loopback only, on a free port: ":0" would listen on all
        # interfaces, and None still starts it, on 127.0.0.1:8787.
        cluster = LocalCluster(n_workers=workers or default_workers(), threads_per_worker=1, processes=True,
                               dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR, **options)
    try:
        yield cluster
    finally:
        cluster.close()


SCHEDULER_TIMEOUT_S = 15.0  # to reach a scheduler and hear back from it, whatever listens there


def _connect(scheduler: str) -> Any:
    """A client of the Dask scheduler at `scheduler` (tcp://HOST:PORT), or one line: another scheme, nothing
    there, or something there that is not a Dask scheduler (silent, or sending other bytes) within
    SCHEDULER_TIMEOUT_S, whatever it does."""
    import threading

    from distributed import Client

    scheme = scheduler.split("://", 1)[0] if "://" in scheduler else "tcp"
    if scheme != "tcp":
        raise ClusterError(f"--scheduler {scheduler}: give the scheduler's tcp://HOST:PORT address ({scheme}:// needs "
                         "Dask settings this command does not take)")
    hint = "start one with 'dask scheduler' and 'dask worker tcp://HOST:8786'"
    outcome: dict[str, Any] = {}

    def connect() -> None:
        try:
            outcome["client"] = Client(scheduler, timeout=f"{SCHEDULER_TIMEOUT_S}s")
        except BaseException as error:  # noqa: BLE001 - handed to the caller as one line
            outcome["error"] = error

    # Dask's own timeout covers connecting, not a peer that accepts and never answers: a thread waits for it.
    thread = threading.Thread(target=connect, name="accel-calib-scheduler", daemon=True)
    thread.start()
    thread.join(SCHEDULER_TIMEOUT_S + 2.0)
    if thread.is_alive():
        raise ClusterError(f"--scheduler {scheduler}: no Dask scheduler answered within {SCHEDULER_TIMEOUT_S:g} s "
                         f"(something else listens there?); {hint}")
    if "error" in outcome:
        error = outcome["error"]
        if isinstance(error, KeyboardInterrupt):
            raise error
        first = str(error).splitlines()[0][:160] if str(error) else ""
        raise ClusterError(f"cannot reach the Dask scheduler {scheduler} ({type(error).__name__}: {first}); "
                         f"{hint}") from None
    return outcome["client"]


@contextlib.contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None) -> Iterator[Any]:
    """A Dask client: of the cluster at `scheduler`, or of a local cluster of `workers` processes that
    lives as long as the block."""
    from distributed import Client

    if scheduler:
        client = _connect(scheduler)
        try:
            yield client
        finally:
            client.close()
        return
    with local_cluster(workers) as cluster:
        client = Client(cluster)
        try:
            yield client
        finally:
            client.close()


def run_tasks(client: Any, function: Callable[..., Any], jobs: Sequence[tuple[Any, ...]], label: str = "recordings",
              sizes: Sequence[int] | None = None) -> Iterator[tuple[int, Any, str | None]]:
    """Submit `function(*job)` for every job and yield (index, result, None) as each finishes, or
    (index, None, one-line reason) when its task raised or its worker died; a progress bar counts them
    (`sizes`: what each job counts for, its recordings where a task takes a batch of them; default 1)."""
    from distributed import as_completed
    from tqdm import tqdm

    futures = [client.submit(function, *job, pure=False) for job in jobs]
    index_of = {future.key: i for i, future in enumerate(futures)}
    counted = list(sizes) if sizes is not None else [1] * len(futures)
    with tqdm(total=sum(counted), unit=label.rstrip("s"), desc=label, disable=None, file=sys.stderr) as bar:
        for future in as_completed(futures):
            i = index_of[future.key]
            try:
                yield i, future.result(), None
            except Exception as error:  # the task's exception, re-raised here, or a lost worker
                text = str(error).splitlines()
                yield i, None, f"{type(error).__name__}: {text[0] if text else ''}"
            finally:
                future.release()
                bar.update(counted[i])


def map_on_local_cluster(function: Callable[..., Any], jobs: Sequence[tuple[Any, ...]], workers: int,
                         failed: Callable[[tuple[Any, ...], str], Any]) -> list[Any]:
    """`function(*job)` for every job on a local cluster of `workers` processes, results in job order
    (`failed(job, reason)` stands in for a task that raised). What `accel-calib replay --jobs` runs."""
    results: list[Any] = [None] * len(jobs)
    with dask_client(workers=min(workers, len(jobs))) as client:
        for i, result, error in run_tasks(client, function, jobs, label="bags"):
            results[i] = failed(jobs[i], error) if error is not None else result
    return results
