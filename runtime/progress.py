"""Progress of long work: a tqdm bar on a terminal, a readable line every few seconds in a log.

tqdm redraws its bar with carriage returns. On a terminal that is one live line; in a log file, a CI transcript
or a batch scheduler's output (stderr not a terminal) the redraws pile up into one very long line that nobody
can read, or vanish. :func:`progress_bar` gives a tqdm bar when stderr is a terminal and a :class:`LogProgress`
otherwise: one plain line every ``PFN_PROGRESS_SECONDS`` seconds (environment variable, default
:data:`LOG_EVERY_S`; 0 prints one line per update) with the share done, the counts, the time spent and the time
left, and a closing line with the total time if any line was printed (a job shorter than the interval prints
nothing, as a finished tqdm bar with ``leave=False`` leaves nothing).

Both have the few methods the product's loops use: ``update(n)``, ``set_postfix(**values)``, ``close()``,
``n`` (the count so far), use as a context manager, and iteration when built over an iterable.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import IO, Any

#: Seconds between two log lines when stderr is not a terminal (overridden by ``PFN_PROGRESS_SECONDS``).
LOG_EVERY_S = 5.0
ENV_SECONDS = "PFN_PROGRESS_SECONDS"


def _count(x: float, scale: bool) -> str:
    """``x`` as tqdm writes counts: 16384 -> "16.4k" with ``scale``, else the integer."""
    if not scale:
        return f"{int(x)}"
    for factor, suffix in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if abs(x) >= factor:
            return f"{x / factor:.1f}{suffix}"
    return f"{int(x)}"


def _interval() -> float:
    text = os.environ.get(ENV_SECONDS)
    if text is None:
        return LOG_EVERY_S
    try:
        value = float(text)
    except ValueError:
        return LOG_EVERY_S
    return value if math.isfinite(value) and value >= 0 else LOG_EVERY_S


class LogProgress:
    """Plain progress lines for logs (module docstring)."""

    def __init__(self, iterable: Iterable[Any] | None = None, *, total: float | None = None, desc: str = "",
                 unit: str = "it", unit_scale: bool = False, every_s: float | None = None,
                 stream: IO[str] | None = None, clock: Callable[[], float] = time.perf_counter) -> None:
        self.iterable = iterable
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)  # type: ignore[arg-type]
        self.total, self.desc, self.unit, self.unit_scale = total, desc, unit, unit_scale
        self.every_s = _interval() if every_s is None else every_s
        self.stream, self.clock = stream, clock
        self.n: float = 0
        self.postfix = ""
        self.start = clock()
        self.last = self.start
        self.lines = 0
        self.closed = False

    def _write(self, text: str) -> None:
        out = self.stream if self.stream is not None else sys.stderr
        out.write(text + "\n")
        out.flush()
        self.lines += 1

    def _line(self, now: float) -> str:
        spent = now - self.start
        done = f"{_count(self.n, self.unit_scale)}"
        if self.total:
            share = min(1.0, self.n / self.total)
            left = f", ~{spent / share - spent:.1f} s left" if 0 < share < 1 else ""
            head = f"{self.desc}: {100 * share:.0f}% ({done}/{_count(self.total, self.unit_scale)} {self.unit})"
        else:
            head, left = f"{self.desc}: {done} {self.unit}", ""
        return f"{head}, {spent:.1f} s{left}" + (f" [{self.postfix}]" if self.postfix else "")

    def update(self, n: float = 1) -> None:
        self.n += n
        now = self.clock()
        if now - self.last >= self.every_s:
            self.last = now
            self._write(self._line(now))

    def set_postfix(self, **values: Any) -> None:
        self.postfix = " ".join(f"{k}={v}" for k, v in values.items())

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        if self.lines:
            unit = f" {_count(self.n, self.unit_scale)} {self.unit}" if self.n else ""
            self._write(f"{self.desc}: done,{unit} in {self.clock() - self.start:.1f} s")

    def __iter__(self) -> Iterator[Any]:
        if self.iterable is None:
            raise TypeError("LogProgress built without an iterable")
        for item in self.iterable:
            yield item
            self.update(1)
        self.close()

    def __enter__(self) -> LogProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def progress_bar(iterable: Iterable[Any] | None = None, *, total: float | None = None, desc: str = "", unit: str = "it",
             unit_scale: bool = False, enabled: bool = True) -> Any:
    """A progress tracker for ``total`` units of work (or over ``iterable``): a tqdm bar (``leave=False``) when
    stderr is a terminal, else a :class:`LogProgress`; ``enabled`` False gives a disabled tqdm (no output)."""
    from tqdm import tqdm

    if not enabled or sys.stderr.isatty():
        return tqdm(iterable, total=total, desc=desc, unit=unit, unit_scale=unit_scale, disable=not enabled,
                    leave=False)
    return LogProgress(iterable, total=total, desc=desc, unit=unit, unit_scale=unit_scale)
