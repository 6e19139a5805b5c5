"""Background retraining for the viewer: a new field for an edited scene, trained in its own process.

After a transfer-function edit (or a light edit the field cannot follow exactly), the field's L_i is stale: it
was trained for the scene before the edit. The viewer keeps rendering (L_d, the path tracer and the camera's
first interactions use the edited scene at once) and starts a :class:`RetrainJob` on the edited scene, run with
this interpreter as ``python -m photon_fields.train.cli.train``, in a folder of its own under the viewer's
output folder: ``pfn-train update`` (a warm-started fine-tune, seconds) when the field in use comes with its
run folder, else ``pfn-train all`` (a cold trace and fit). The runtime never imports torch: training is another
process, which is also what lets the page cancel it (a new edit) without waiting.

The job reports through ``pfn-train --progress-file`` (:mod:`photon_fields.runtime.io.progress`); the session
polls it, shows it in the page, and swaps the new bundle in when the job is done.

Cores: the job trains with ``threads`` workers (1 by default) and the session renders with the rest while it
runs, so that neither stalls the other on a 2-core machine.

Folder of job ``NNNN`` (``OUT/retrain/NNNN/``): ``scene.json`` (the edited scene, a scene file), ``progress.json``,
``train.log`` (the trainer's output, whose last line is the error of a failed job) and ``run/`` (the run
folder: ``map.npz``, ``checkpoint.pt``, ``log.json``, ``loss.png``, ``field.pfn``).
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.io.atomic import atomic_write_text
from photon_fields.runtime.io.progress import Progress, read_progress
from photon_fields.runtime.scene.scene import Scene

#: The trainer, as this interpreter runs it.
TRAINER = (sys.executable, "-m", "photon_fields.train.cli.train")


@dataclass(frozen=True)
class RetrainSettings:
    """How the viewer retrains.

    photons: photon records of the new map (fewer than ``pfn-train``'s default: the retrace is part of an
        interactive edit cycle; the same seed keeps the paths correlated with the earlier map's).
    preset: ``pfn-train --preset``; steps: ``--steps`` (None: the preset's).
    threads: the job's worker threads; the viewer renders with the other cores while it runs.
    delay_s: seconds an edit must rest before a job starts (a dragged control point sends many edits).
    auto: start a job after every edit that makes L_i stale (else only when the page asks).
    budget_s: ``pfn-train update --budget`` of a warm-started job, seconds for retrace and training on
        ``threads`` cores (None: update's default).
    extra: more ``pfn-train all`` options (tests: a tiny preset).
    command: the trainer program (None: :data:`TRAINER`; tests put a stand-in here).
    """

    photons: str = "1M"
    preset: str = "cpu"
    steps: int | None = None
    threads: int = 1
    delay_s: float = 1.5
    auto: bool = True
    budget_s: float | None = 30.0
    extra: tuple[str, ...] = ()
    command: tuple[str, ...] | None = None


def unavailable_reason(settings: RetrainSettings) -> str | None:
    """Why this installation cannot retrain (None: it can). Checked without importing torch."""
    if settings.command is not None:
        return None
    for module in ("torch", "photon_fields.train"):
        if importlib.util.find_spec(module) is None:
            return ("retraining needs the train extra (pip install 'photon-fields[train]'); until then L_i "
                    "stays the field's as trained")
    return None


class RetrainJob:
    """One background training of ``scene`` in ``folder`` (module docstring), started at once."""

    def __init__(self, scene: Scene, folder: Path, settings: RetrainSettings, *, seed: int = 0,
                 edited_at: float | None = None, warm_from: Path | None = None) -> None:
        spec = scene.spec()
        if spec is None:
            raise InputError("retrain", "this scene's volume was built in memory and cannot be handed to the "
                                        "trainer; load the scene from a file to retrain")
        self.scene, self.folder, self.settings = scene, Path(folder), settings
        self.started = time.monotonic()
        self.edited_at = self.started if edited_at is None else edited_at
        self.folder.mkdir(parents=True, exist_ok=False)
        atomic_write_text(self.scene_file, json.dumps(spec, indent=1) + "\n")
        self.warm_from = warm_from
        common = ["--out", str(self.run_dir), "--threads", str(settings.threads), "--quiet", "--progress-file",
                  str(self.progress_file)]
        if warm_from is not None:  # fine-tune the field in use: its run folder's weights, map seed, settings
            cmd = [*(settings.command or TRAINER), "update", str(warm_from), "--scene", str(self.scene_file),
                   *common, "--photons", settings.photons,
                   *(["--budget", str(settings.budget_s)] if settings.budget_s is not None else [])]
        else:
            cmd = [*(settings.command or TRAINER), "all", str(self.scene_file), *common, "--photons",
                   settings.photons, "--preset", settings.preset, "--seed", str(int(seed)),
                   *(["--steps", str(settings.steps)] if settings.steps is not None else []), *settings.extra]
        self.log = open(self.log_file, "wb")  # noqa: SIM115  (closed when the job ends)
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        try:
            self.process = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=self.log,
                                            stderr=subprocess.STDOUT, env=env, start_new_session=True)
        except OSError:
            self.log.close()
            raise
        self.ended: float | None = None
        self.cancelled = False

    @property
    def scene_file(self) -> Path:
        return self.folder / "scene.json"

    @property
    def progress_file(self) -> Path:
        return self.folder / "progress.json"

    @property
    def log_file(self) -> Path:
        return self.folder / "train.log"

    @property
    def run_dir(self) -> Path:
        return self.folder / "run"

    @property
    def bundle(self) -> Path:
        return self.run_dir / "field.pfn"

    @property
    def photon_map(self) -> Path:
        return self.run_dir / "map.npz"

    def poll(self) -> tuple[str, Progress | None, str | None]:
        """(state, progress, message): state is ``"running"``, ``"done"``, ``"failed"`` or ``"cancelled"``;
        message is a failed job's one-line error. A job is done once its progress file says so and its bundle is
        there (written atomically and verified before that): the trainer's own exit (the interpreter tearing torch
        and its thread pools down, ~1 s) is not waited for; :meth:`exited` tells when it has gone."""
        code = self.process.poll()
        try:
            progress = read_progress(self.progress_file)
        except InputError:
            progress = None
        if code is None:
            if not self.cancelled and progress is not None and progress.status == "done" and self.bundle.exists():
                self._close()
                return "done", progress, None
            return "running", progress, None
        self._close()
        if self.cancelled:
            return "cancelled", progress, None
        if code == 0 and progress is not None and progress.status == "done" and self.bundle.exists():
            return "done", progress, None
        message = progress.message if progress is not None and progress.status == "failed" else None
        return "failed", progress, message or self._last_log_line() or f"the trainer exited with status {code}"

    def exited(self) -> bool:
        """Whether the trainer's process has ended (a done job's may still be exiting)."""
        return self.process.poll() is not None

    def cancel(self) -> None:
        """Stop the job (its process group) and wait for it; its folder stays for inspection."""
        if self.process.poll() is None:
            self.cancelled = True
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.process.pid, signal.SIGTERM)
            try:
                self.process.wait(10.0)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait(10.0)
        self._close()

    def _close(self) -> None:
        if self.ended is None:
            self.ended = time.monotonic()
        if not self.log.closed:
            self.log.close()

    def _last_log_line(self) -> str | None:
        try:
            lines = [ln.strip() for ln in self.log_file.read_text(errors="replace").replace("\r", "\n").splitlines()]
        except OSError:
            return None
        lines = [ln for ln in lines if ln]
        return " ".join(lines[-1].split())[:300] if lines else None


def next_job_folder(out_dir: Path) -> Path:
    """``OUT/retrain/NNNN``: the first number not used yet (earlier jobs' folders are never replaced)."""
    root = Path(out_dir) / "retrain"
    root.mkdir(parents=True, exist_ok=True)
    used = [int(p.name) for p in root.iterdir() if p.name.isdigit()]
    return root / f"{max(used, default=0) + 1:04d}"


def status_message(state: str, progress: Progress | None = None, message: str | None = None,
                   **extra: Any) -> dict[str, Any]:
    """The ``retrain`` text message the page shows (its progress bar and line)."""
    return {"type": "retrain", "state": state,
            "stage": progress.stage if progress else None,
            "fraction": round(progress.fraction, 4) if progress else (1.0 if state == "done" else 0.0),
            "elapsed_s": round(progress.elapsed_s, 1) if progress else None,
            "message": message, **extra}
