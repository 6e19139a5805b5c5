"""One line when numba starts compiling in this process, so that a silent first render is explained.

The first run after an install or an upgrade compiles the renderers' kernels: half a minute to two minutes on 2 cores
(bench/README.md, "Cold compiles"), during which a progress bar sits at 0 % and a command looks hung. numba fires its
``numba:compile`` event only for a real compile (a kernel found in its cache is loaded without one), so a warm run
says nothing. ``pfn-render`` and ``pfn-view`` announce it (not with ``--quiet``).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

#: What the commands say (after their own name) when the first kernel compiles.
MESSAGE = ("compiling its kernels for this machine: the first run after an install or an upgrade takes a minute or "
           "two; later runs load them from numba's cache")


def announce_compiles(say: Callable[[str], None]) -> None:
    """Call ``say(MESSAGE)`` once, at the first numba compile in this process after this call (none if every kernel
    comes from the cache)."""
    from numba.core import event

    lock = threading.Lock()
    said = [False]

    class _Notice(event.Listener):
        def on_start(self, ev: Any) -> None:
            with lock:
                if said[0]:
                    return
                said[0] = True
            say(MESSAGE)

        def on_end(self, ev: Any) -> None:
            pass

    event.register("numba:compile", _Notice())
