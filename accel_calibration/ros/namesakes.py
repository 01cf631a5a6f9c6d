"""Another node of this one's fully qualified name, or another node offering its calibrate service: looked
for at NAMESAKE_CHECKS_S after start (the graph takes a while to show them), each found logged once and
kept for /diagnostics (a WARN)."""
from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from rclpy.node import Node

from .diagnostics import NAMESAKE_CHECKS_S, namesake_problem, service_twins_problem

__all__ = ["NamesakeLook"]


class NamesakeLook:
    def __init__(self, node: Node, calibrate_service: str, started: float,
                 guard: Callable[[str, Callable[[], None]], Any]):
        self._node, self._calibrate_service, self._started = node, calibrate_service, started
        self.found: str | None = None  # what the looks found so far, one line
        self._looks = 0  # of NAMESAKE_CHECKS_S done
        self._timer = node.create_timer(1.0, guard("namesakes", self.look))

    def look(self) -> None:
        looks_due = sum(1 for at in NAMESAKE_CHECKS_S if time.monotonic() - self._started >= at)
        if looks_due <= self._looks:
            return
        self._looks = looks_due
        if looks_due == len(NAMESAKE_CHECKS_S):
            self._timer.cancel()
        own = self._node.get_fully_qualified_name()
        graph = self._node.get_node_names_and_namespaces()
        problems = [namesake_problem(own, graph), service_twins_problem(self._calibrate_service,
                                                                         self._offering_calibrate(own, graph))]
        said = self.found or ""
        for problem in problems:
            if problem is not None and problem not in said:
                self._node.get_logger().warning(problem)
        found = "; ".join(problem for problem in problems if problem is not None)
        self.found = found or self.found

    def _offering_calibrate(self, own: str, graph: list[tuple[str, str]]) -> list[str]:
        """The other nodes (fully qualified names) that offer this node's calibrate service."""
        offering = []
        for name, namespace in graph:
            fqn = f"{namespace.rstrip('/')}/{name}"
            if fqn == own:
                continue
            try:
                services = self._node.get_service_names_and_types_by_node(name, namespace)
            except Exception:  # noqa: BLE001 - the node left the graph meanwhile
                continue
            if any(service == self._calibrate_service for service, _ in services):
                offering.append(fqn)
        return offering
