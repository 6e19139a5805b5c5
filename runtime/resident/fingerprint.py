"""What must match for a resident server to run a client's render as the client itself would: the code, and
the environment a process reads when it starts.

**Code** (:func:`code_fingerprint`): a hash of the Python version and executable, the distributions installed
beside it (the names of the ``*.dist-info`` and ``*.egg-info`` entries in site-packages, which carry every
version, this package's, numpy's and numba's included) and the path, size and mtime_ns of every file of the
packages a render imports: ``photon_fields`` itself (api/), ``photon_fields.runtime`` and
``photon_fields.models_spec``. Not ``photon_fields.train``: the runtime never imports it (tests/test_layout.py),
so work on training does not retire a server. A ``stat`` per file and one folder listing: ~1 ms for ~140 files,
cheap enough for every ``pfn-render`` call (bench/README.md, ``bench_cli_startup.py``). Edited or reinstalled code
changes it; a server whose code on disk changed since it started stops (modules it imports later would come from
the new code).

**Process environment** (:func:`process_environment`): the variables read once, when numba, OpenMP, a BLAS or this
package load: ``NUMBA_*``, ``OMP_*``, ``KMP_*``, ``OPENBLAS_*``, ``MKL_*``, ``PYTHONPATH`` and ``PFN_*``
(``PFN_CACHE``, ...) but the two below. A server started with other values could render differently (threads,
threading layer, another module path), so they must be equal, absent ones included.

**Job environment** (:func:`job_environment`): the variables a render reads while it runs: ``PFN_PROGRESS_SECONDS``
(runtime/progress.py), ``TQDM_*`` (tqdm's defaults), ``COLUMNS`` and ``LINES`` (the width of ``--help`` and of
progress bars). They are not compared: each job carries the client's and the server sets them for its duration.
``PFN_RESIDENT_DIR`` chooses the server and changes no render: it is neither.

Standard library only: ``pfn-render`` computes this before numpy or numba are imported.
"""

from __future__ import annotations

import importlib.util
import os
import sys
from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from typing import Any

#: Prefixes of the variables read at process start (module docstring).
PROCESS_PREFIXES = ("NUMBA_", "OMP_", "KMP_", "OPENBLAS_", "MKL_", "PFN_")
PROCESS_NAMES = ("PYTHONPATH",)
#: Variables each job carries and the server sets for its duration.
JOB_NAMES = ("PFN_PROGRESS_SECONDS", "COLUMNS", "LINES")
JOB_PREFIXES = ("TQDM_",)
#: Neither: the server's folder.
NEUTRAL_NAMES = ("PFN_RESIDENT_DIR",)
#: The packages a render imports: (module, whether its subfolders count). ``photon_fields`` is flat (api/); in a
#: regular install its folder also holds the others, which are walked on their own (train is not).
CODE_PACKAGES = (("photon_fields", False), ("photon_fields.runtime", True), ("photon_fields.models_spec", True))


def is_job_variable(name: str) -> bool:
    return name in JOB_NAMES or name.startswith(JOB_PREFIXES)


def process_environment(environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """The process-start variables of ``environ`` (default ``os.environ``), sorted by name."""
    env = os.environ if environ is None else environ
    return {k: env[k] for k in sorted(env)
            if (k in PROCESS_NAMES or k.startswith(PROCESS_PREFIXES)) and k not in NEUTRAL_NAMES
            and not is_job_variable(k)}


def job_environment(environ: Mapping[str, str] | None = None) -> dict[str, str]:
    """The per-job variables of ``environ`` (default ``os.environ``), sorted by name."""
    env = os.environ if environ is None else environ
    return {k: env[k] for k in sorted(env) if is_job_variable(k)}


def code_roots() -> list[tuple[str, bool]]:
    """The folders of :data:`CODE_PACKAGES` as this interpreter imports them (found without importing them)."""
    roots = []
    for name, recursive in CODE_PACKAGES:
        spec = importlib.util.find_spec(name)
        if spec is None or not spec.submodule_search_locations:
            raise ImportError(f"{name} is not installed as a package")
        roots += [(os.path.abspath(folder), recursive) for folder in spec.submodule_search_locations]
    return roots


def _files(folder: str, recursive: bool) -> Iterator[tuple[str, int, int]]:
    """(path, size, mtime_ns) of the files under ``folder``, skipping hidden entries and ``__pycache__``."""
    with os.scandir(folder) as entries:
        found = sorted(entries, key=lambda e: e.name)
    for entry in found:
        if entry.name.startswith(".") or entry.name == "__pycache__":
            continue
        if entry.is_dir(follow_symlinks=False):
            if recursive:
                yield from _files(entry.path, True)
        elif entry.is_file():
            st = entry.stat()
            yield entry.path, st.st_size, st.st_mtime_ns


def installed_distributions() -> list[str]:
    """The names of the distribution metadata entries in site-packages (they carry the versions)."""
    import site

    names: list[str] = []
    folders = site.getsitepackages() if hasattr(site, "getsitepackages") else []
    for folder in folders:
        try:
            with os.scandir(folder) as entries:
                names += [f"{folder}/{e.name}" for e in entries if e.name.endswith((".dist-info", ".egg-info"))]
        except OSError:
            continue
    return sorted(names)


def _hasher() -> Any:
    try:  # blake2b without hashlib's OpenSSL import (~4 ms of a client's start-up)
        from _blake2 import blake2b
    except ImportError:  # pragma: no cover (every CPython build has _blake2)
        from hashlib import blake2b
    return blake2b(digest_size=16)


def code_fingerprint(roots: list[tuple[str, bool]] | None = None) -> str:
    """The hex fingerprint of the installed code (module docstring); ``roots``: other package folders (tests)."""
    h = _hasher()
    h.update(f"{sys.version}\0{sys.executable}\0".encode())
    for name in installed_distributions():
        h.update(f"{name}\0".encode("utf-8", "surrogateescape"))
    for folder, recursive in code_roots() if roots is None else roots:
        h.update(f"\1{folder}\0".encode("utf-8", "surrogateescape"))
        for path, size, mtime_ns in _files(folder, recursive):
            h.update(f"{path}\0{size}\0{mtime_ns}\0".encode("utf-8", "surrogateescape"))
    return h.hexdigest()
