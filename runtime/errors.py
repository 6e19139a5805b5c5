"""User-facing errors.

Every problem with user input (files, scene descriptions, CLI arguments) is raised as an
:class:`InputError` whose message is one line naming the input and the problem. The command-line
entry points catch it, print ``error: <message>`` to stderr and exit with status 2, so users never
see a deep traceback for a mistake of theirs.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Mapping, Sequence
from typing import Any


class InputError(ValueError):
    """Bad user input. ``str(err)`` is a single line: '<input>: <problem>'."""

    def __init__(self, what: str, problem: str) -> None:
        self.what = str(what)
        self.problem = " ".join(str(problem).split())  # keep it on one line
        super().__init__(f"{self.what}: {self.problem}")


def unknown_keys_problem(unknown: Sequence[str], allowed: Iterable[str]) -> str:
    """``unknown key 'densty_scale' (did you mean 'density_scale'?); allowed: 'density_scale', 'points'``."""
    allowed = sorted(allowed)
    names = ", ".join(repr(str(k)) for k in unknown)
    text = f"unknown key{'s' if len(unknown) > 1 else ''} {names}"
    guesses = [g for k in unknown for g in difflib.get_close_matches(str(k), allowed, n=1, cutoff=0.75)]
    if len(guesses) == len(unknown):
        text += f" (did you mean {', '.join(repr(g) for g in guesses)}?)"
    return f"{text}; allowed: {', '.join(repr(k) for k in allowed)}"


def check_keys(d: Mapping[str, Any], allowed: Iterable[str], what: str, required: Iterable[str] = ()) -> None:
    """Refuse a JSON object with keys outside ``allowed`` (a typo must not silently fall back to a default),
    then one without every key of ``required``; ``what`` names the file and the entry."""
    allowed = set(allowed)
    unknown = [k for k in d if k not in allowed]
    if unknown:
        raise InputError(what, unknown_keys_problem(unknown, allowed))
    missing = [k for k in required if k not in d]
    if missing:
        raise InputError(what, f"missing {', '.join(repr(k) for k in missing)}")
