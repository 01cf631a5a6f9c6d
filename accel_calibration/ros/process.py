"""The node's process: rclpy started with our own signal handling, the node spun in slices until a signal,
and torn down so that a save in flight finishes (the file is then the old or the new one, whole)."""
from __future__ import annotations

import gc
import signal
import sys
import threading
from collections.abc import Callable
from typing import Any

import rclpy
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from ..core.errors import AccelCalibrationError
from ..live.calibration_work import LOG_THROTTLE_S
from .parameters import asks_for_help, first_line, params_file_problem, usage

__all__ = ["GIL_SWITCH_INTERVAL_S", "run_node", "spin_until"]

GIL_SWITCH_INTERVAL_S = 0.0005


def spin_until(node: Node, stop: threading.Event) -> None:
    """EventsExecutor costs ~2.4x less CPU per message than the SingleThreadedExecutor here; its
    spin() without a timeout busy-loops in the PyPI wheel, so spin in slices (PERF_NOTES), which
    also lets the loop see `stop` (set by a signal) within 0.1 s."""
    from rclpy.experimental import EventsExecutor

    executor = EventsExecutor()
    executor.add_node(node)
    never: rclpy.task.Future = rclpy.task.Future()
    try:
        while not stop.is_set() and rclpy.ok():
            try:
                executor.spin_until_future_complete(never, timeout_sec=0.1)
            except Exception as error:  # noqa: BLE001 - a callback that escaped its guard must not end the node
                node.get_logger().error(f"executor: {type(error).__name__}: {error}; carrying on",
                                        throttle_duration_sec=LOG_THROTTLE_S)
    finally:
        executor.remove_node(node)


def run_node(program: str, make_node: Callable[[], Node], args: list[str] | None = None) -> int:
    """Start ROS, build the node, spin it until SIGINT/SIGTERM, tear down. A bad start is one line, exit 2."""
    stop = threading.Event()
    argv = sys.argv[1:] if args is None else args
    if asks_for_help(argv):
        print(usage(program))
        return 0
    problem = params_file_problem(argv)
    if problem is not None:
        print(f"{program}: error: {problem}", file=sys.stderr)
        return 2
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as error:  # noqa: BLE001 - a broken --ros-args / --params-file: one line, exit 2
        print(f"{program}: error: cannot start ROS: {first_line(error)}", file=sys.stderr)
        return 2

    def on_signal(signum: int, frame: Any) -> None:
        stop.set()  # the spin loop ends; a second signal (a terminal under ros2 launch) changes nothing

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    # The work runs in its own process; here only the pipe's thread (the work's snapshots, ~5 a second)
    # competes with the executor for the GIL, for at most the switch interval (5 ms by default) while a
    # message waits for its callback: 0.5 ms keeps that wait below the stream's own jitter.
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    node: Any = None
    try:
        try:
            node = make_node()
        except AccelCalibrationError as error:
            print(f"{program}: error: {error}", file=sys.stderr)
            return 2
        except Exception as error:  # noqa: BLE001 - rclpy's own refusals (e.g. a value outside a range)
            print(f"{program}: error: {first_line(error)}", file=sys.stderr)
            return 2
        # Everything made so far (rclpy, numpy, the node) lives as long as the process: out of the
        # collector's reach, a full collection scans only what the stream makes, not ~20 ms of startup
        # objects with the executor's thread held up meanwhile.
        gc.freeze()
        if not stop.is_set():
            spin_until(node, stop)
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        rclpy.try_shutdown()
        # Python's finalisation puts SIG_DFL back for every handler it installed, so a second SIGINT
        # in the last milliseconds (a terminal under ros2 launch) would kill the process (-2): ignored
        # handlers are left alone, and there is nothing left to stop.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    return 0
