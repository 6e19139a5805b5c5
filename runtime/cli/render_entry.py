"""The ``pfn-render`` console script: the resident render server when one can take the job, else the render in
this process, as always.

A fresh ``pfn-render`` spends about a second importing numba and loading its kernels before any work (bench/README.md,
``bench_cli_startup.py``). This module therefore imports nothing but the standard library and the stdlib-only client
(:mod:`photon_fields.runtime.resident.client`) before asking this user's resident server (``pfn-resident start``,
docs/resident.md) to run the command line; the server runs :mod:`photon_fields.runtime.cli.render`'s own main
with this process's folder, output streams and environment, and this process prints what it prints and exits with
its status. When no compatible server is running, or with ``--no-resident``, the render runs here, silently the
same as before (:func:`photon_fields.runtime.cli.render.main`).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from typing import Any

NO_RESIDENT = "--no-resident"
#: The shortest abbreviation argparse accepts for it (``--no-`` alone is also ``--no-nee``).
_SHORTEST = "--no-r"


def in_process_requested(argv: Sequence[str]) -> bool:
    """Whether ``argv`` asks for ``--no-resident``, spelt out or abbreviated as argparse allows, before any
    ``--`` (after which arguments are not options)."""
    for arg in argv:
        if arg == "--":
            return False
        if arg.startswith(_SHORTEST) and NO_RESIDENT.startswith(arg):
            return True
    return False


def server_socket_exists() -> bool:
    """Whether this user's server folder holds a socket: without one, no server runs, and the client (its socket and
    JSON modules, ~10 ms) is not even imported."""
    from photon_fields.runtime.resident.paths import ResidentDirError, resident_paths

    try:
        return os.path.exists(resident_paths().socket)
    except ResidentDirError:
        return False


def main(argv: Sequence[str] | None = None) -> None:
    """``pfn-render``: through the resident server if one takes the job, else in this process; exits with the
    render's status."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not in_process_requested(args) and server_socket_exists():
        from photon_fields.runtime.resident.client import render_through_server

        try:
            status = render_through_server(args)
        except KeyboardInterrupt:  # before the job started (the client handles it once it runs)
            print("error: interrupted", file=sys.stderr)
            sys.exit(130)
        if status is not None:
            sys.exit(status)
    from photon_fields.runtime.cli.render import main as render_main

    render_main(args)


def __getattr__(name: str) -> Any:
    """``_main``: the in-process entry (:func:`photon_fields.runtime.cli.render._main`), imported on use, for tools
    that run a console script's command in-process (tests/runtime/cli/test_catalogue.py)."""
    if name == "_main":
        from photon_fields.runtime.cli.render import _main

        return _main
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
