"""User-facing errors.

Every problem with user input (files, scene descriptions, CLI arguments) is raised as an
:class:`InputError` whose message is one line naming the input and the problem. The command-line
entry points catch it, print ``error: <message>`` to stderr and exit with status 2, so users never
see a deep traceback for a mistake of theirs.
"""

from __future__ import annotations


class InputError(ValueError):
    """Bad user input. ``str(err)`` is a single line: '<input>: <problem>'."""

    def __init__(self, what: str, problem: str) -> None:
        self.what = str(what)
        self.problem = " ".join(str(problem).split())  # keep it on one line
        super().__init__(f"{self.what}: {self.problem}")
