"""Where a user's resident render server lives: one private folder per user on this machine.

The folder is ``$PFN_RESIDENT_DIR`` when set (tests; or a user who wants it elsewhere), else
``$XDG_RUNTIME_DIR/photon-fields`` (a per-user tmpfs on systemd machines, emptied at logout), else
``photon-fields/resident`` under ``$XDG_CACHE_HOME`` or ``~/.cache``. It is created with mode 0700, and refused
(:class:`ResidentDirError`) unless it is a real folder (not a symbolic link), owned by this user, that no one
else may enter: the socket in it is the server's only door, and the folder's permissions are what keep other
users away from it (the server checks the peer's uid as well, :func:`photon_fields.runtime.resident.protocol.peer_uid`).

Its files: ``render.sock`` (the Unix socket, mode 0600), ``resident.lock`` (locked by the running server for its
whole life: whoever holds it is the server, so a socket left behind by a killed one is known to be stale and is
replaced), ``resident.log`` (what the server did: start, jobs, stop).

Standard library only: ``pfn-render`` reads this before numpy or numba are imported.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Mapping

ENV_DIR = "PFN_RESIDENT_DIR"
SOCKET_NAME = "render.sock"
LOCK_NAME = "resident.lock"
LOG_NAME = "resident.log"
#: The longest socket path Linux takes (``sun_path`` is 108 bytes with the terminating NUL).
MAX_SOCKET_PATH = 107


class ResidentDirError(Exception):
    """The server's folder cannot be used; ``str(err)`` is one line naming it and the problem."""


class ResidentPaths:
    """The folder and the files in it (module docstring)."""

    __slots__ = ("folder",)

    def __init__(self, folder: str) -> None:
        self.folder = folder

    @property
    def socket(self) -> str:
        return os.path.join(self.folder, SOCKET_NAME)

    @property
    def lock(self) -> str:
        return os.path.join(self.folder, LOCK_NAME)

    @property
    def log(self) -> str:
        return os.path.join(self.folder, LOG_NAME)


def default_folder(environ: Mapping[str, str] | None = None) -> str:
    """The folder's path for ``environ`` (default ``os.environ``), absolute (module docstring)."""
    env = os.environ if environ is None else environ
    chosen = env.get(ENV_DIR)
    if chosen:
        return os.path.abspath(os.path.expanduser(chosen))
    runtime = env.get("XDG_RUNTIME_DIR")
    if runtime and os.path.isabs(runtime) and os.path.isdir(runtime):
        return os.path.join(runtime, "photon-fields")
    cache = env.get("XDG_CACHE_HOME")
    if not cache or not os.path.isabs(cache):
        cache = os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(cache, "photon-fields", "resident")


def resident_paths(environ: Mapping[str, str] | None = None, *, create: bool = False) -> ResidentPaths:
    """The checked folder (created, mode 0700, when ``create``); a :class:`ResidentDirError` when it is missing
    (without ``create``), not private to this user, or too deep for a socket path."""
    folder = default_folder(environ)
    if create:
        try:
            os.makedirs(folder, mode=0o700, exist_ok=True)
        except OSError as exc:
            raise ResidentDirError(f"{folder}: cannot create the folder: {exc.strerror or exc}") from None
    check_private(folder)
    paths = ResidentPaths(folder)
    if len(os.fsencode(paths.socket)) > MAX_SOCKET_PATH:
        raise ResidentDirError(f"{folder}: too long for a socket path ({len(os.fsencode(paths.socket))} bytes, at "
                               f"most {MAX_SOCKET_PATH}); set {ENV_DIR} to a shorter folder")
    return paths


def check_private(folder: str) -> None:
    """Refuse ``folder`` unless it is a folder (not a link) owned by this user with no access for others."""
    try:
        st = os.lstat(folder)
    except FileNotFoundError:
        raise ResidentDirError(f"{folder}: no such folder") from None
    except OSError as exc:
        raise ResidentDirError(f"{folder}: {exc.strerror or exc}") from None
    if not stat.S_ISDIR(st.st_mode):
        raise ResidentDirError(f"{folder}: not a folder (a link or a file); the server needs a private folder")
    if st.st_uid != os.getuid():
        raise ResidentDirError(f"{folder}: owned by uid {st.st_uid}, not by this user ({os.getuid()})")
    if st.st_mode & 0o077:
        raise ResidentDirError(f"{folder}: mode {stat.S_IMODE(st.st_mode):04o} lets other users in; it must be "
                               "0700 (chmod 700 it)")
