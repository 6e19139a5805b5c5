"""Worker-thread control for numba's pool, in one place.

numba's thread count is process-wide state. Command-line tools set it once for the whole run
(:func:`set_threads`); library code that must not leave a change behind, such as a photon field queried with
its own thread count, sets it for the duration of a call (:func:`numba_threads`). Both refuse a count
outside ``[1, NUMBA_NUM_THREADS]`` in one line naming the input.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from photon_fields.runtime.errors import InputError


def max_threads() -> int:
    """The most numba threads this process can use (``NUMBA_NUM_THREADS``, normally the core count)."""
    import numba

    return int(numba.config.NUMBA_NUM_THREADS)


def check_threads(threads: int | None, name: str = "--threads") -> int | None:
    """``threads`` if it is None (all cores) or an integer in ``[1, max_threads()]``, else an InputError."""
    if threads is None:
        return None
    upper = max_threads()
    if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= upper:
        raise InputError(name, f"must be an integer in [1, {upper}], got {threads!r}")
    return threads


def set_threads(threads: int | None, name: str = "--threads") -> None:
    """Limit numba's worker threads for the rest of the process (None: leave all cores)."""
    if check_threads(threads, name) is None:
        return
    import numba

    numba.set_num_threads(threads)


@contextlib.contextmanager
def numba_threads(threads: int | None, name: str = "threads") -> Iterator[None]:
    """Run the body with ``threads`` numba workers and restore the previous count after it (None: unchanged)."""
    if check_threads(threads, name) is None:
        yield
        return
    import numba

    previous = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        yield
    finally:
        numba.set_num_threads(previous)
