"""``--progress-file``, the option of every long ``pfn-train`` job: the job's progress as one JSON object that
``pfn-view`` reads (format: :mod:`photon_fields.runtime.io.progress`).

:func:`add_progress_option` adds the option to a subcommand's parser (:func:`add_job_options` adds it with the
other options every long job shares), :func:`open_progress` opens the file when it
is given (written at once, so a reader sees the job start), :func:`stage_callback` turns one stage into the
``on_progress(done, total)`` callback the tracing, fitting and precomputation take, and :func:`record_failure`
marks the file failed with the error's line when a job stops on an exception.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from pathlib import Path

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.io.progress import Progress, ProgressFile, read_progress


def add_job_options(p: argparse.ArgumentParser, *, replaces: str) -> None:
    """The options every long ``pfn-train`` job shares: ``--threads``, ``--quiet``, ``--force`` (whose help says
    what it replaces: ``replaces``) and ``--progress-file``."""
    p.add_argument("--threads", type=int, default=None, help="worker threads (default: all cores)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--force", action="store_true", help=f"replace {replaces}")
    add_progress_option(p)


def add_progress_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--progress-file", default=None,
                   help="also write the progress as JSON to this file (replaced atomically, read by pfn-view; "
                        "format: photon_fields.runtime.io.progress)")


def open_progress(args: argparse.Namespace, stages: Sequence[str]) -> ProgressFile | None:
    """The job's progress file, or None without --progress-file; written at once so a reader sees the job start."""
    if args.progress_file is None:
        return None
    path = Path(args.progress_file)
    if not path.parent.is_dir():
        raise InputError("--progress-file", f"the folder of {str(path)!r} does not exist")
    progress = ProgressFile(path, stages)
    progress.update(stages[0], 0, 0)
    return progress


def stage_callback(progress: ProgressFile | None, stage: str) -> Callable[[int, int], None] | None:
    """The ``on_progress(done, total)`` callback of one stage."""
    return None if progress is None else (lambda done, total: progress.update(stage, done, total))


def record_failure(args: argparse.Namespace, exc: BaseException) -> None:
    """Mark the progress file failed with the error's one line (what pfn-view shows), if the job wrote one."""
    path = getattr(args, "progress_file", None)
    if path is None or not Path(path).parent.is_dir():
        return
    line = str(exc) if isinstance(exc, InputError) else f"{type(exc).__name__}: {exc}"
    previous = read_progress_quietly(path)
    progress = ProgressFile(path, previous.stages if previous else ())
    if previous is not None:
        progress.update(previous.stage, previous.done, previous.total)
    progress.finish("failed", line or type(exc).__name__)


def read_progress_quietly(path: str) -> Progress | None:
    try:
        return read_progress(path)
    except InputError:
        return None
