"""When a viewer session retrains its field: start after edits rest, cancel on a newer edit, hand over the result.

A :class:`FieldUpdater` belongs to one page's session. The event-loop thread tells it what the page wants
(:meth:`FieldUpdater.want` after an edit that makes L_i stale, :meth:`FieldUpdater.cancel`); both only record
the wish, in microseconds. The render thread calls :meth:`FieldUpdater.poll` between frames: it starts a
:class:`photon_fields.runtime.viewer.retrain.RetrainJob` once the newest edit has rested for
``settings.delay_s`` (cancelling a job still training for an older edit), follows its progress, and returns the
finished job for the session to load. The edit cycle's time runs from the first edit that made the field stale
to the finished job.
"""

from __future__ import annotations

import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.labels import LabelTransfer
from photon_fields.runtime.scene.scene import Scene
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.viewer.retrain import (
    RetrainJob,
    RetrainSettings,
    next_job_folder,
    status_message,
    unavailable_reason,
)

#: Seconds between two progress messages of a running job (a stage change is sent at once).
STATUS_INTERVAL = 0.5


def same_transfer(a: TransferFunction | LabelTransfer | None, b: TransferFunction | LabelTransfer | None) -> bool:
    """Whether two transfer functions give the same medium (their names aside): the same control points; for
    label functions the same extinction per label and the same albedo wherever a label is seen (a label at
    opacity 0, named or not, is transparent either way, so the label panel's function, which names every label,
    equals the scene's own until an edit changes what is seen). A label function never equals a scalar one."""
    if a is b:
        return True
    if a is None or b is None:
        return False
    if isinstance(a, LabelTransfer) or isinstance(b, LabelTransfer):
        return isinstance(a, LabelTransfer) and isinstance(b, LabelTransfer) and _seen_labels(a) == _seen_labels(b)
    return (a.density_scale == b.density_scale and np.array_equal(a.points, b.points)
            and np.array_equal(a.albedo, b.albedo) and np.array_equal(a.opacity, b.opacity))


def _seen_labels(tf: LabelTransfer) -> dict[int, tuple[float, ...]]:
    """label -> (extinction, albedo) of the labels a label function does not leave transparent."""
    return {int(label): (float(o) * tf.density_scale, *(float(c) for c in alb))
            for label, alb, o in zip(tf.labels, tf.albedo, tf.opacity, strict=True) if o > 0}


class FieldUpdater:
    """Background retraining of one session's field (module docstring)."""

    def __init__(self, out_dir: Path, settings: RetrainSettings, *, seed: int = 0) -> None:
        self.out_dir, self.settings, self.seed = Path(out_dir), settings, int(seed)
        self.reason = unavailable_reason(settings)
        self.lock = threading.Lock()
        self.job: RetrainJob | None = None
        self._exiting: list[RetrainJob] = []  # done jobs whose trainers are still exiting
        self._wanted: Scene | None = None
        self._warm_from: Path | None = None
        self._wanted_at = 0.0
        self._edited_at: float | None = None  # the first edit since the field in use was made
        self._cancel = False
        self._auto_waits = False  # an automatic retrain waits for the page to leave PVRT (auto_after)
        self._last_status: dict[str, Any] | None = None
        self._last_sent = 0.0

    @property
    def available(self) -> bool:
        return self.reason is None

    @property
    def busy(self) -> bool:
        """A job is training (the session then renders with the cores it leaves)."""
        return self.job is not None and self.job.process.poll() is None

    def want(self, scene: Scene, now: bool = False, warm_from: Path | None = None) -> None:
        """A field for ``scene`` is wanted: after ``settings.delay_s`` without a newer wish, or at the next poll
        when ``now``; fine-tuned from the run folder ``warm_from`` when given (else trained from scratch)."""
        with self.lock:
            t = time.monotonic()
            self._wanted, self._wanted_at, self._cancel = scene, t - (self.settings.delay_s if now else 0.0), False
            self._warm_from = warm_from
            if self._edited_at is None:
                self._edited_at = t

    def auto_after(self, edit: bool, stale: bool, pvrt_shown: bool) -> bool:
        """Whether a page message starts an automatic retrain (the caller then calls :meth:`want`): an ``edit``
        (transfer function, labels, a light) that leaves the field ``stale``, or else (a switch of renderer) a retrain
        that was waiting. While PVRT is shown (``pvrt_shown``) it waits: PVRT relights from its own transfer, and a
        job would take a core from its light drags for a field nobody looks at. :meth:`cancel` drops the wait."""
        if not (edit or self._auto_waits) or not (self.settings.auto and stale):
            return False
        self._auto_waits = pvrt_shown
        return not pvrt_shown

    def cancel(self) -> None:
        """Drop the wish (and a retrain waiting for the page to leave PVRT) and stop the running job at the next
        poll."""
        with self.lock:
            self._wanted, self._cancel, self._auto_waits = None, True, False

    def status(self) -> dict[str, Any] | None:
        """The last status message (None before any job)."""
        return self._last_status

    def poll(self) -> tuple[dict[str, Any] | None, RetrainJob | None]:
        """(a status message for the page if there is news, the job that just finished successfully or None)."""
        with self.lock:
            wanted, wanted_at, cancel, warm_from = self._wanted, self._wanted_at, self._cancel, self._warm_from
            start = wanted is not None and time.monotonic() - wanted_at >= self.settings.delay_s
            if start or cancel:
                self._wanted = None if start else self._wanted
                self._cancel = False
        if cancel and self.job is not None:
            self.job.cancel()
            self.job = None
            with self.lock:
                self._edited_at = None
            return self.emit(status_message("cancelled", message="retraining cancelled")), None
        if start:
            if self.reason is not None:
                return self.emit(status_message("unavailable", message=self.reason)), None
            if self.job is not None:
                self.job.cancel()
            try:
                self.job = RetrainJob(wanted, next_job_folder(self.out_dir), self.settings, seed=self.seed,
                                      edited_at=self._edited_at, warm_from=warm_from)
            except (InputError, OSError) as exc:
                self.job = None
                return self.emit(status_message("failed", message=f"cannot start retraining: {exc}")), None
            return self.emit(status_message("running", folder=str(self.job.folder),
                                             warm_start=warm_from is not None)), None
        self._exiting = [j for j in self._exiting if not j.exited()]
        if self.job is None:
            return None, None
        state, progress, message = self.job.poll()
        if state == "running":
            last = self._last_status or {}
            news = progress is not None and (progress.stage != last.get("stage")
                                             or time.monotonic() - self._last_sent >= STATUS_INTERVAL)
            return (self.emit(status_message("running", progress, folder=str(self.job.folder))) if news
                    else None), None
        job, self.job = self.job, None
        if not job.exited():
            self._exiting.append(job)  # done, its trainer still exiting: reaped by a later poll or close()
        if state == "done":
            with self.lock:
                self._edited_at = None
            cycle = (job.ended or time.monotonic()) - job.edited_at
            return self.emit(status_message("done", progress, f"new field in {cycle:.0f} s", cycle_s=round(cycle, 1),
                                             folder=str(job.folder))), job
        return self.emit(status_message(state, progress, message, folder=str(job.folder))), None

    def failed(self, message: str) -> dict[str, Any]:
        """A finished job whose field could not be loaded: the page is told, the current field stays."""
        return self.emit(status_message("failed", message=message))

    def close(self) -> None:
        """Stop a running job (the page went away); wait for done jobs' trainers still exiting."""
        if self.job is not None:
            self.job.cancel()
            self.job = None
        for job in self._exiting:
            try:
                job.process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                job.cancel()
        self._exiting = []

    def emit(self, status: dict[str, Any]) -> dict[str, Any]:
        """Record ``status`` as the last one sent to the page (what :meth:`status` returns) and return it."""
        self._last_status, self._last_sent = status, time.monotonic()
        return status
