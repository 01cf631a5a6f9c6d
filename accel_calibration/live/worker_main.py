"""The worker process's entry point. Nothing here loads numpy: OpenBLAS reads its thread count once, when
numpy is first imported, and the work wants one thread (OpenBLAS's threads spin on its thin products and
would take a core from the stream), unless the user chose a number."""
from __future__ import annotations

import os
import pickle
from typing import Any


def main(conn: Any, rings: tuple[Any, Any], start: bytes) -> None:
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from .worker_loop import run_worker

    run_worker(conn, rings, pickle.loads(start))
