"""User-facing errors.

Every problem with user input (files, scene descriptions, CLI arguments) is raised as an
:class:`InputError` whose message is one line naming the input and the problem. The command-line
entry points catch it, print ``error: <message>`` to stderr and exit with status 2, so users never
see a deep traceback for a mistake of theirs.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any

from photon_fields.models_spec.json_keys import keys_problem, unknown_keys_problem
from photon_fields.models_spec.npz_manifest import NpzError

__all__ = ["InputError", "check_choice", "check_keys", "unknown_keys_problem", "npz_errors_as_input"]


class InputError(ValueError):
    """Bad user input. ``str(err)`` is a single line: '<input>: <problem>'."""

    def __init__(self, what: str, problem: str) -> None:
        self.what = str(what)
        self.problem = " ".join(str(problem).split())  # keep it on one line
        super().__init__(f"{self.what}: {self.problem}")


def check_choice(what: str, value: Any, choices: tuple[str, ...]) -> str:
    """``value`` if it is one of ``choices``, else one line naming ``what`` and the choices."""
    if value not in choices:
        raise InputError(what, f"must be one of {', '.join(choices)}, got {value!r}")
    return value


def check_keys(d: Mapping[str, Any], allowed: Iterable[str], what: str, required: Iterable[str] = ()) -> None:
    """Refuse a JSON object with keys outside ``allowed`` (a typo must not silently fall back to a default),
    then one without every key of ``required``; ``what`` names the file and the entry."""
    problem = keys_problem(d, allowed, required)
    if problem is not None:
        raise InputError(what, problem)


@contextmanager
def npz_errors_as_input() -> Iterator[None]:
    """Re-raise the contract's :class:`~photon_fields.models_spec.npz_manifest.NpzError` (a photon map or transfer
    file refused by ``models_spec``, which cannot import this module) as an :class:`InputError` of the same text."""
    try:
        yield
    except NpzError as err:
        raise InputError(err.what, err.problem) from None
