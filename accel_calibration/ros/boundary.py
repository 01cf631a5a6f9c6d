"""The node's boundary with rclpy: no exception from a callback may end the node, and services that need
the worker are answered when its job ends, so the executor (and the corrected stream) never waits."""
from __future__ import annotations

import collections
import functools
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

from rclpy.node import Node

from ..live.calibration_work import LOG_THROTTLE_S
from ..live.worker_protocol import WorkerGone

Fallback = Callable[[tuple[Any, ...], Exception], Any]


class Boundary:
    """Guards callbacks of one node and counts their failures by callback name."""

    def __init__(self, node: Node):
        self.node = node
        self.errors: collections.Counter[str] = collections.Counter()

    def guard(self, name: str, callback: Callable[..., Any], fallback: Fallback | None = None) -> Callable[..., Any]:
        """The callback, with any exception logged (throttled), counted and answered by `fallback`."""

        @functools.wraps(callback)
        def guarded(*args: Any) -> Any:
            try:
                return callback(*args)
            except Exception as error:  # noqa: BLE001 - the boundary itself
                self.errors[name] += 1
                self.node.get_logger().error(f"{name} callback failed ({type(error).__name__}: {error}); "
                                             "the node carries on", throttle_duration_sec=LOG_THROTTLE_S)
                return None if fallback is None else fallback(args, error)

        return guarded

    def deferred_service(self, srv_type: Any, name: str, start: Callable[[Any], Future[tuple[bool, str]]],
                         qos_profile: Any) -> None:
        """A Trigger-like service (success, message) answered when the job `start(request)` returns ends."""
        deferred: dict[int, Future[tuple[bool, str]]] = {}

        def callback(request: Any, response: Any) -> Any:
            try:
                job = start(request)
            except Exception as error:  # noqa: BLE001 - the boundary itself
                self.errors[name] += 1
                response.success, response.message = False, f"{name} failed: {type(error).__name__}: {error}"
                return response
            deferred[id(response)] = job
            return response

        service = self.node.create_service(srv_type, name, callback, qos_profile=qos_profile)
        send_now = service.send_response

        def send_response(response: Any, header: Any) -> None:
            job = deferred.pop(id(response), None)
            if job is None:
                send_now(response, header)
                return

            def answer(done: Future[tuple[bool, str]]) -> None:
                try:
                    response.success, response.message = done.result()
                except WorkerGone as gone:  # the work was not there to do it: said, not counted as a failure
                    response.success, response.message = False, f"{name} not done: {gone}"
                except Exception as error:  # noqa: BLE001 - cancelled at shutdown, or a job that failed
                    self.errors[name] += 1
                    response.success, response.message = False, f"{name} not done: {type(error).__name__}: {error}"
                try:
                    send_now(response, header)
                except Exception:  # noqa: BLE001 - the context is gone at shutdown; nobody to answer
                    pass

            job.add_done_callback(answer)

        # rclpy has no deferred-response API: the executor sends what the callback returns through this
        # (public) method, so the instance's is wrapped to send once the worker's job is done.
        service.send_response = send_response  # type: ignore[method-assign]


def failed_service(args: tuple[Any, ...], error: Exception) -> Any:
    """Fallback of a guarded service callback (request, response): the response says what failed."""
    response = args[-1]
    response.success = False
    response.message = f"internal error ({type(error).__name__}: {error}); the node carries on"
    return response
