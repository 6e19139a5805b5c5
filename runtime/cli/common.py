"""Pieces shared by the command-line tools (``pfn-render``, ``pfn-train``): one-line errors, argument
checks, output paths that are never replaced without ``--force``."""

from __future__ import annotations

import argparse
import os
import re
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

from photon_fields.runtime.errors import InputError


class OneLineArgumentParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are :class:`InputError` s, so that a mistyped option gives the
    same single ``error: <input>: <problem>`` line as every other bad input (argparse would print the
    whole usage block)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        m = re.match(r"argument (\S+): (.*)", message, flags=re.DOTALL)
        if m:  # "argument --spp: invalid int value: 'abc'" -> "--spp: invalid int value: 'abc'"
            raise InputError(m.group(1).split("/")[-1], m.group(2) + " (see --help)")
        raise InputError("command line", message + " (see --help)")


def guarded(main_fn: Callable[[Sequence[str] | None], int]) -> Callable[[Sequence[str] | None], int]:
    """Turn InputError into one line on stderr and exit status 2; Ctrl-C into status 130."""

    def wrapper(argv: Sequence[str] | None = None) -> int:
        try:
            return main_fn(argv)
        except InputError as err:
            print(f"error: {err}", file=sys.stderr)
            return 2
        except (KeyboardInterrupt, SystemError) as err:
            if not interrupted(err):  # a SystemError not caused by Ctrl-C
                raise
            print("error: interrupted", file=sys.stderr)
            return 130

    return wrapper


def interrupted(err: BaseException) -> bool:
    """Whether ``err`` is a KeyboardInterrupt or was caused by one. Ctrl-C during a call into a numba kernel often
    reaches Python as ``SystemError: CPUDispatcher(...) returned a result with an exception set`` caused by the
    KeyboardInterrupt (the dispatcher's C code returned while the handler's exception was pending), which printed a
    traceback and exit status 1 instead of ``error: interrupted`` and 130 (tests/runtime/cli/test_cli.py)."""
    seen: set[int] = set()
    cause: BaseException | None = err
    while cause is not None and id(cause) not in seen:
        if isinstance(cause, KeyboardInterrupt):
            return True
        seen.add(id(cause))
        cause = cause.__cause__ or cause.__context__
    return False


def positive_int(name: str, value: int, upper: int = 1 << 30) -> int:
    if not 1 <= value <= upper:
        raise InputError(name, f"must be an integer in [1, {upper}], got {value}")
    return value


def check_seed(seed: int, name: str = "--seed") -> int:
    # Random streams are keyed by 64-bit integers; anything wider would overflow inside the kernels.
    if not -(1 << 63) <= seed < (1 << 63):
        raise InputError(name, f"must be a 64-bit signed integer, got {seed}")
    return seed


def prepare_output(out: Path, suffix: str, siblings: Sequence[str] = (), name: str = "--out", *,
                   force: bool = False, what: str = "an earlier result", create: bool = True) -> None:
    """Fail before the work, not after: check the suffix, that no folder sits where an output file goes,
    that no earlier output would be replaced without ``force`` (:func:`refuse_to_replace`), and create the
    parent folder (``create=False``: leave that to :func:`make_parent`, once the other inputs passed)."""
    if out.suffix.lower() != suffix:
        raise InputError(name, f"must end in {suffix}, got {str(out)!r}")
    targets = [out, *(out.with_suffix(s) for s in siblings)]
    for target in targets:
        if target.is_dir():
            raise InputError(name, f"{str(target)!r} is a folder, cannot write an output file there")
    refuse_to_replace(targets, force, what, name)
    if create:
        make_parent(out, name)


def make_parent(out: Path, name: str = "--out") -> None:
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(name, f"cannot create the folder {str(out.parent)!r}: {exc.strerror or exc}") from None


def refuse_to_replace(paths: Iterable[Path], force: bool, what: str, name: str = "--out") -> list[Path]:
    """Nothing already on disk is lost without ``--force``: refuse, in one line naming what exists, when
    any of ``paths`` exists. Returns the existing paths (which ``force`` lets the command replace)."""
    found = [p for p in paths if p.exists() or p.is_symlink()]
    if found and not force:
        shown = ", ".join(str(p) for p in found[:3]) + (f" and {len(found) - 3} more" if len(found) > 3 else "")
        raise InputError(name, f"{what} exists ({shown}); pass --force to replace it")
    return found


_COUNT = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([kKmMgG]?)\s*$")


def parse_count(text: str, what: str = "--photons") -> int:
    """'1M' -> 1_000_000, '250k' -> 250_000, '4000' -> 4000."""
    m = _COUNT.match(str(text))
    if not m:
        raise InputError(what, f"expected a count such as 1M, 250k or 4000, got {text!r}")
    value = float(m.group(1)) * {"": 1, "k": 1e3, "m": 1e6, "g": 1e9}[m.group(2).lower()]
    if value < 1 or value != int(value):
        raise InputError(what, f"must be a positive whole number, got {text!r}")
    return int(value)


def process_started() -> float:
    """The ``time.perf_counter()`` at which this process started (Linux: ``/proc/self/stat``; elsewhere now): a
    command's own start-up (the interpreter, its imports) then counts against a time budget the user gave it."""
    now = time.perf_counter()
    try:
        ticks = int(Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()[19])  # field 22, starttime
        age = time.clock_gettime(time.CLOCK_BOOTTIME) - ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, AttributeError):
        return now
    return now - min(max(age, 0.0), 3600.0)
