"""Progress of long work, for another process to read: a small JSON file replaced atomically as work advances.

``pfn-train ... --progress-file PATH`` writes it (tracing, fitting, export); the viewer reads it to show a
background retrain's progress bar. Every write replaces the whole file (:func:`atomic_write_text`), so a reader
sees either the previous state or the new one, never half of it. Writes are throttled to one per
``min_interval`` seconds except for stage changes and the end.

The file holds one object with exactly these keys (:data:`PROGRESS_KEYS`; a reader refuses any other):

- ``stage``: what runs now (``"trace"``, ``"fit"``, ``"export"``, ...);
- ``done``, ``total``: work units of that stage (photons, steps, ...), ``0 <= done <= total``;
- ``stages``: the stages of the whole job in order, so a reader can show overall progress;
- ``elapsed_s``: seconds since the job started;
- ``status``: ``"running"``, ``"done"`` or ``"failed"``;
- ``message``: None, or one line: the error of a failed job, the result of a finished one.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from photon_fields.runtime.errors import InputError, check_keys
from photon_fields.runtime.io.atomic import atomic_write_text

PROGRESS_KEYS = ("stage", "done", "total", "stages", "elapsed_s", "status", "message")
STATUSES = ("running", "done", "failed")


@dataclass(frozen=True)
class Progress:
    """One reading of a progress file (module docstring for the fields)."""

    stage: str
    done: int
    total: int
    stages: tuple[str, ...]
    elapsed_s: float
    status: str
    message: str | None = None

    @property
    def fraction(self) -> float:
        """Overall progress in [0, 1], each stage counted as an equal share of the job."""
        if self.status == "done":
            return 1.0
        n = max(len(self.stages), 1)
        index = self.stages.index(self.stage) if self.stage in self.stages else 0
        return min(1.0, (index + (self.done / self.total if self.total > 0 else 0.0)) / n)


class ProgressFile:
    """Writes a job's progress to ``path`` (module docstring). ``stages``: the job's stages in order."""

    def __init__(self, path: str | Path, stages: Sequence[str], *, min_interval: float = 0.5) -> None:
        self.path = Path(path)
        self.stages = tuple(stages)
        self.min_interval = float(min_interval)
        self.t0 = time.perf_counter()
        self._last_write = -float("inf")
        self._stage: str | None = None
        self._done = self._total = 0

    def update(self, stage: str, done: int, total: int) -> None:
        """``done`` of ``total`` units of ``stage`` are finished; written at once on a stage change, else at most
        every ``min_interval`` seconds."""
        now = time.perf_counter()
        changed = stage != self._stage
        self._stage, self._done, self._total = stage, int(done), int(total)
        if changed or now - self._last_write >= self.min_interval:
            self._write("running", None)
            self._last_write = now

    def finish(self, status: str = "done", message: str | None = None) -> None:
        """The job ended (``"done"`` or ``"failed"``), with an optional one-line message."""
        if status not in ("done", "failed"):
            raise ValueError(f"finish status must be done or failed, got {status!r}")
        if status == "done" and self._stage is not None:
            self._done = self._total
        self._write(status, message)

    def _write(self, status: str, message: str | None) -> None:
        stage = self._stage if self._stage is not None else (self.stages[0] if self.stages else "")
        p = Progress(stage, self._done, self._total, self.stages, round(time.perf_counter() - self.t0, 3), status,
                     None if message is None else " ".join(str(message).split()))
        atomic_write_text(self.path, json.dumps({**asdict(p), "stages": list(p.stages)}) + "\n")


def read_progress(path: str | Path) -> Progress | None:
    """The progress in ``path``; None while the file does not exist yet. A file that is not a progress object
    (unknown or missing keys, wrong types) is an :class:`InputError` naming it."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None
    what = f"progress file {str(p)!r}"
    try:
        d: Any = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(what, f"is not JSON ({exc.msg})") from None
    if not isinstance(d, dict):
        raise InputError(what, "must hold a JSON object")
    check_keys(d, PROGRESS_KEYS, what, required=PROGRESS_KEYS)
    ok = (isinstance(d["stage"], str) and _is_count(d["done"]) and _is_count(d["total"])
          and isinstance(d["stages"], list) and all(isinstance(s, str) for s in d["stages"])
          and isinstance(d["elapsed_s"], (int, float)) and not isinstance(d["elapsed_s"], bool)
          and d["status"] in STATUSES and (d["message"] is None or isinstance(d["message"], str)))
    if not ok or d["done"] > d["total"]:
        raise InputError(what, "has a field of the wrong type or range")
    return Progress(d["stage"], d["done"], d["total"], tuple(d["stages"]), float(d["elapsed_s"]), d["status"],
                    d["message"])


def _is_count(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v >= 0
