"""fleet's one writer of the history: the workers' outcomes written in batches, said and counted.

A transaction per outcome cost the command (the client, on the same cores as the workers) more than a
flight log's replay costs a worker; a batch of rows is one transaction per table. A batch the database
refuses is written again row by row, so a row still stands or fails alone (`failed` with the database's
reason), and nothing is said of a recording before its row is written."""
from __future__ import annotations

import sys
import time
from typing import Any, Protocol


class RecordingOutcome(Protocol):
    """What this writer reads of cli/fleet.RecordingOutcome (named here: fleet imports this module)."""

    @property
    def path(self) -> str: ...
    @property
    def status(self) -> str: ...  # calibrated | refused | failed
    @property
    def reason(self) -> str | None: ...
    @property
    def record(self) -> Any: ...  # io/history.HistoryRecord, or None
    @property
    def summary(self) -> str: ...
    @property
    def evidence(self) -> Any: ...  # io/flight_history.EvidenceRecord, or None

BATCH_ROWS = 256  # outcomes held at most before they are written
BATCH_S = 2.0  # nor held longer than this once the first of them arrived


class HistoryWriter:
    """Outcomes in, rows out: `add` each outcome (and its further IMUs'), `flush` at the end. `rows` maps a
    row's key to the recordings written to it (one content, one row); `counts` by status and evidence."""

    def __init__(self, history: Any) -> None:
        self.history = history
        self.rows: dict[str, list[str]] = {}
        self.counts = {"calibrated": 0, "refused": 0, "failed": 0, "evidence": 0, "no evidence": 0,
                       "estimator": 0, "agreement": 0}
        self._pending: list[RecordingOutcome] = []
        self._since = 0.0

    def add(self, outcome: RecordingOutcome) -> None:
        if not self._pending:
            self._since = time.monotonic()
        self._pending.append(outcome)
        if len(self._pending) >= BATCH_ROWS or time.monotonic() - self._since >= BATCH_S:
            self.flush()

    def flush(self) -> None:
        pending, self._pending = self._pending, []
        if not pending:
            return
        written = self._write_records(pending)
        evidence_errors = self._write_evidence(pending)
        for outcome, row_written in written:
            self._said(outcome, row_written)
        for error in evidence_errors:
            _error_line(error)

    def _write_records(self, pending: list[RecordingOutcome]) -> list[tuple[RecordingOutcome, bool]]:
        """The calibrations' rows in one transaction, or row by row when it is refused: (outcome, its row
        written), an outcome whose row the database refused turned `failed` with its reason."""
        from ..io.history import HistoryError

        records = [o.record for o in pending if o.record is not None]
        try:
            self.history.write(records)
            return [(o, o.record is not None) for o in pending]
        except HistoryError:
            pass  # one bad row: find it, the others are written alone
        out = []
        for outcome in pending:
            written = outcome.record is not None
            if outcome.record is not None:
                try:
                    self.history.write([outcome.record])
                except HistoryError as error:
                    outcome, written = _unwritten(outcome, error), False
            out.append((outcome, written))
        return out

    def _write_evidence(self, pending: list[RecordingOutcome]) -> list[str]:
        """The flight evidence rows in one transaction, or row by row when it is refused: the errors."""
        from ..io.history import HistoryError

        evidence = [o.evidence for o in pending if o.evidence is not None]
        try:
            self.history.write_evidence(evidence)
            self._count_evidence(evidence)
            return []
        except HistoryError:
            pass
        errors = []
        for record in evidence:
            try:
                self.history.write_evidence([record])
                self._count_evidence([record])
            except HistoryError as error:
                errors.append(str(error))
        return errors

    def _count_evidence(self, evidence: list[Any]) -> None:
        for record in evidence:
            self.counts["evidence" if record.status == "evidence" else "no evidence"] += 1
            self.counts["estimator"] += _said_in_flight(record.estimator)
            self.counts["agreement"] += _said_in_flight(record.agreement)

    def _said(self, outcome: RecordingOutcome, row_written: bool) -> None:
        from tqdm import tqdm

        from ..core.text import printable_text

        if row_written and outcome.record is not None:
            self.rows.setdefault(outcome.record.recording_id, []).append(outcome.path)
        self.counts[outcome.status] += 1
        if outcome.status == "calibrated":  # printable whatever bytes a file name holds
            tqdm.write(printable_text(outcome.summary))
        else:
            _error_line(str(outcome.reason))


def _error_line(text: str) -> None:
    from tqdm import tqdm

    from ..core.text import printable_text

    tqdm.write(f"accel-calib: error: {printable_text(text)}", file=sys.stderr)


def _unwritten(outcome: RecordingOutcome, error: Exception) -> RecordingOutcome:
    """A recording whose row the database refused: failed, with the database's reason, the others go on."""
    import dataclasses

    reason = f"{outcome.path}: its row was not written ({error})"
    unwritten: RecordingOutcome = dataclasses.replace(outcome, status="failed", reason=reason,  # type: ignore[type-var]
                                                      summary=f"failed     {reason}", others=())
    return unwritten


def _said_in_flight(stored: str | None) -> bool:
    """An in-flight column (JSON) that holds a measurement, not the reason there is none."""
    import json

    if not stored:
        return False
    try:
        said = json.loads(stored)
    except ValueError:
        return False
    return isinstance(said, dict) and "reason" not in said
