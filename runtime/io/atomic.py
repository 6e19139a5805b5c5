"""Atomic file output: a file either appears complete under its final name or not at all.

Every writer of user-visible outputs (EXR/PNG images, JSON reports, NPZ bundles, raw volumes) goes
through :func:`atomic_path`, so an interrupted run (exception, Ctrl-C, full disk) never leaves a
truncated file behind and never clobbers a good file from an earlier run.

Conventions:

- The temporary file lives in the *same directory* as the target (so :func:`os.replace` is an atomic
  rename on one file system) and is named ``.<name>.<random>.tmp<suffix>``: it is hidden, and it keeps
  the target's suffix (``.exr``, ``.png``, ``.npz``, ``.nii.gz`` ...) because several libraries pick
  the output format from the file name (PIL) or append a suffix when it is missing (``numpy.savez``).
- The temporary file is created empty (``O_EXCL``, mode ``0o666`` filtered by the umask, like a file
  created with ``open(path, "w")``); writers may overwrite or truncate it.
- On success it is fsync'ed, renamed over the target and the directory entry is fsync'ed (best effort).
- On any exception (including ``KeyboardInterrupt``) it is deleted and the exception propagates; a
  pre-existing target file is left untouched.
- The parent directory must exist; it is not created here.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterator
from pathlib import Path

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text"]

_COMPRESSION_SUFFIXES = {".gz", ".bz2", ".xz", ".zst", ".lz4"}


def _target_suffix(path: Path) -> str:
    """The suffix to keep on the temp file: ``.png``; two parts for compressed files (``.nii.gz``)."""
    suffixes = path.suffixes
    if len(suffixes) >= 2 and suffixes[-1].lower() in _COMPRESSION_SUFFIXES:
        return "".join(suffixes[-2:])
    return path.suffix


def _create_temp(path: Path, suffix: str) -> Path:
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp{suffix}")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
        except FileExistsError:
            continue
        os.close(fd)
        return tmp
    raise FileExistsError(f"could not create a unique temporary file next to {path}")


def _fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDWR | getattr(os, "O_BINARY", 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_dir(directory: Path) -> None:
    """Persist a rename (POSIX only; silently skipped where directories cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], *, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` if the block succeeds.

    Write the output to the yielded path (use ``str(tmp)`` for libraries that want a string)::

        with atomic_path("out/image.exr") as tmp:
            write_exr(str(tmp), pixels)

    ``suffix`` overrides the suffix kept on the temporary name (default: the target's suffix).
    If the block raises, the temporary file is removed and any existing ``path`` is unchanged.
    """
    target = Path(path)
    tmp = _create_temp(target, _target_suffix(target) if suffix is None else suffix)
    try:
        yield tmp
        _fsync_file(tmp)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    fsync_dir(target.parent)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path`)."""
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(data)


def atomic_write_text(path: str | os.PathLike[str], text: str, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically (see :func:`atomic_path`); newlines are written as-is."""
    atomic_write_bytes(path, text.encode(encoding))
