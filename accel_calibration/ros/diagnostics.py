"""What the node says on /diagnostics: one DiagnosticStatus built from the worker's latest progress, the
counters and the stream's health (a silent input is a WARN naming the resolved topic)."""
from __future__ import annotations

from dataclasses import dataclass

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from ..core.calibration import Calibration
from ..core.session import Progress
from ..core.stream.screening import Counters


@dataclass(frozen=True)
class StreamHealth:
    """Seconds since the last message on each input (None: none yet), the node's age and the resolved
    topic names."""

    imu_topic: str
    temperature_topic: str
    imu_silent_s: float | None
    temperature_silent_s: float | None
    timeout_s: float
    uptime_s: float

    def problem_by_input(self) -> dict[str, str]:
        """Each silent input ("imu", "temperature") and what to say of it, one line."""
        out = {}
        if self.imu_silent_s is None and self.uptime_s >= self.timeout_s:
            out["imu"] = f"no messages on {self.imu_topic} since start ({self.uptime_s:.0f} s)"
        elif self.imu_silent_s is not None and self.imu_silent_s >= self.timeout_s:
            out["imu"] = f"no messages on {self.imu_topic} for {self.imu_silent_s:.0f} s"
        if self.temperature_silent_s is not None and self.temperature_silent_s >= self.timeout_s:
            out["temperature"] = (f"no messages on {self.temperature_topic} for {self.temperature_silent_s:.0f} s "
                                  "(temperature stale)")
        return out

    def problems(self) -> list[str]:
        return list(self.problem_by_input().values())


def waiting_advice(imu_topic: str) -> str:
    """The advice before any Imu message came: no orientation to turn to yet."""
    return f"waiting for data on {imu_topic}: no Imu message yet"


FIRST_REMINDER_S = 10.0
MAX_REMINDER_S = 320.0  # a silence of hours is still said every few minutes, not every few seconds


class SilenceReminders:
    """When the log says again that an input is still silent: at once, then after FIRST_REMINDER_S,
    each interval twice the last, up to MAX_REMINDER_S. An input that speaks again starts over, so a new
    silence is said at once. /diagnostics says it every second regardless."""

    def __init__(self) -> None:
        self._next: dict[str, tuple[float, float]] = {}  # input -> (when due, the interval after that)

    def due(self, problems: dict[str, str], now: float) -> list[str]:
        """The lines to log now, from problem_by_input()."""
        for gone in set(self._next) - set(problems):
            del self._next[gone]
        lines = []
        for key, text in problems.items():
            when, interval = self._next.get(key, (now, FIRST_REMINDER_S))
            if now >= when:
                lines.append(f"{text} (said again in {interval:.0f} s if it lasts)")
                self._next[key] = (now + interval, min(2.0 * interval, MAX_REMINDER_S))
        return lines


def diagnostic_status(name: str, level: bytes, message: str, progress: Progress, values: dict[str, str],
                      counts: dict[str, int], errors: dict[str, int], calibration: Calibration | None,
                      hardware_id: str, health: StreamHealth, pause_reasons: tuple[str, ...]) -> DiagnosticStatus:
    if level == DiagnosticStatus.OK and any(v for k, v in counts.items() if k not in Counters.INFORMATIONAL):
        level = DiagnosticStatus.WARN
    silent = health.problems()
    if silent and level == DiagnosticStatus.OK:
        level = DiagnosticStatus.WARN
    advice = progress.advice
    if health.imu_silent_s is None:  # nothing to turn yet: the sensor is not heard at all
        advice = waiting_advice(health.imu_topic)
    elif calibration is not None and not progress.ready and progress.poses < progress.min_poses:
        # Calibrated (from a file, or earlier): the missing faces only refine it.
        advice = f"calibration in force; more poses would refine it ({advice})"
    entries = {
        "poses": str(progress.poses),
        "poses_needed": str(progress.min_poses),
        "missing_directions": ", ".join(progress.missing) or "none",
        "advice": advice,
        "fit_residual_rms_mg": "" if progress.residual_rms_mg is None else f"{progress.residual_rms_mg:.3f}",
        "fit_bias_sigma_max_mg": "" if progress.max_bias_sigma_mg is None else f"{progress.max_bias_sigma_mg:.3f}",
        **values,
        "imu_silent_s": "" if health.imu_silent_s is None else f"{health.imu_silent_s:.1f}",
        "temperature_silent_s": "" if health.temperature_silent_s is None else f"{health.temperature_silent_s:.1f}",
    }
    span = progress.temperature_span_degc
    entries["temperature_span_degc"] = "" if span is None else f"{span[0]:.1f}..{span[1]:.1f} ({span[1] - span[0]:.1f})"
    entries["temperature_model"] = progress.temperature_status
    entries.update({key: str(value) for key, value in counts.items()})
    for callback, count in errors.items():
        entries[f"callback_errors.{callback}"] = str(count)
    if calibration is not None and calibration.quality is not None:
        entries["calibration_residual_rms_mg"] = f"{calibration.quality.residual_rms_mg:.3f}"
    paused = f" (collection paused: {', '.join(pause_reasons)})" if pause_reasons else ""
    text = "; ".join([message, *silent, advice]) + paused
    return DiagnosticStatus(level=level, name=name, message=text, hardware_id=hardware_id,
                            values=[KeyValue(key=k, value=v) for k, v in entries.items()])


# Seconds after start at which the node looks for another node of its own name: discovery takes a few
# seconds, and a namesake started later is seen at a later look. Never on the stream's path.
NAMESAKE_CHECKS_S = (2, 5, 10, 20, 40, 80)


def namesake_problem(fully_qualified_name: str, names_and_namespaces: list[tuple[str, str]]) -> str | None:
    """One line when the graph holds this node's fully qualified name more than once (rclpy's
    get_node_names_and_namespaces, which lists this node too)."""
    count = sum(1 for name, namespace in names_and_namespaces
                if f"{namespace.rstrip('/')}/{name}" == fully_qualified_name)
    if count < 2:
        return None
    return (f"{count} nodes are named {fully_qualified_name}: they share its services and parameters, and by "
            "default its calibration file; give each its own name or namespace (-r __node:=... or -r __ns:=...)")


def service_twins_problem(service: str, offering: list[str]) -> str | None:
    """One line when other nodes (`offering`: their fully qualified names) offer this node's calibrate service:
    nodes of other names in one namespace each answer every call, and the caller takes one answer."""
    if not offering:
        return None
    return (f"{len(offering) + 1} nodes offer {service}: this one and {', '.join(sorted(offering))}; each answers "
            "every call and the caller takes one answer: give each its own namespace (-r __ns:=...)")
