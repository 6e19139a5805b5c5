"""Progress in logs (runtime/progress.py): plain lines at a fixed interval, a closing line, nothing for short work."""

from __future__ import annotations

import io
import re

import pytest

from photon_fields.runtime.progress import LogProgress, progress_bar


class Clock:
    """A clock the test moves by hand."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def _log(clock: Clock, **kw) -> tuple[LogProgress, io.StringIO]:  # noqa: ANN003
    out = io.StringIO()
    return LogProgress(stream=out, clock=clock, every_s=5.0, **kw), out


def test_a_line_every_interval_with_share_counts_and_time_left() -> None:
    clock = Clock()
    bar, out = _log(clock, total=20_000, desc="tracing photons", unit="ph", unit_scale=True)
    with bar:
        for _ in range(12):  # one update per second of 1000 photons
            clock.t += 1.0
            bar.update(1000)
    lines = out.getvalue().splitlines()
    assert lines == ["tracing photons: 25% (5.0k/20.0k ph), 5.0 s, ~15.0 s left",
                     "tracing photons: 50% (10.0k/20.0k ph), 10.0 s, ~10.0 s left",
                     "tracing photons: done, 12.0k ph in 12.0 s"]
    assert "\r" not in out.getvalue()


def test_short_work_prints_nothing_and_postfix_is_shown() -> None:
    clock = Clock()
    bar, out = _log(clock, total=10, desc="fitting", unit="step")
    bar.update(3)
    bar.close()
    assert out.getvalue() == ""
    bar, out = _log(clock, total=10, desc="fitting", unit="step")
    bar.set_postfix(loss="0.1234", r="0.01")
    clock.t += 6.0
    bar.update(5)
    assert out.getvalue().splitlines()[0] == "fitting: 50% (5/10 step), 6.0 s, ~6.0 s left [loss=0.1234 r=0.01]"


def test_iteration_counts_items() -> None:
    clock = Clock()
    bar, out = _log(clock, desc="orbit", unit="frame", iterable=range(4))
    seen = []
    for i in bar:
        clock.t += 3.0
        seen.append(i)
    assert seen == [0, 1, 2, 3]
    assert re.fullmatch(r"orbit: 50% \(2/4 frame\), 6\.0 s, ~6\.0 s left\norbit: 100% \(4/4 frame\), 12\.0 s\n"
                        r"orbit: done, 4 frame in 12\.0 s\n", out.getvalue())


def test_factory_uses_log_lines_off_a_terminal(monkeypatch: pytest.MonkeyPatch) -> None:
    """stderr captured by pytest is not a terminal: a LogProgress; disabled: a silent tqdm; the interval comes
    from PFN_PROGRESS_SECONDS (a bad value falls back to the default)."""
    monkeypatch.setenv("PFN_PROGRESS_SECONDS", "2.5")
    bar = progress_bar(total=4, desc="x")
    assert isinstance(bar, LogProgress) and bar.every_s == 2.5
    monkeypatch.setenv("PFN_PROGRESS_SECONDS", "soon")
    assert progress_bar(total=4, desc="x").every_s == 5.0
    quiet = progress_bar(total=4, desc="x", enabled=False)
    assert not isinstance(quiet, LogProgress) and quiet.disable
