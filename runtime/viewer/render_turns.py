"""Renders of all sessions of a viewer process take turns (:func:`render_turn`), and idle work gives way to them.

Two pages rendering at once would each get half the cores and both miss their frame rate; one at a time keeps each
frame as fast as the machine allows. The same lock guards the work a render thread does between frames
(:mod:`photon_fields.runtime.viewer.idle_work`: the light volumes' margins, which the sessions' scenes may share):
it runs only when no frame holds the lock, and stops between chunks as soon as a frame of any page is waiting
(:func:`frames_waiting`).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

RENDER_LOCK = threading.Lock()
_count_lock = threading.Lock()
_waiting = 0


@contextmanager
def render_turn() -> Iterator[None]:
    """Hold :data:`RENDER_LOCK` for a frame, counted among the frames waiting while it waits for it."""
    global _waiting
    with _count_lock:
        _waiting += 1
    try:
        RENDER_LOCK.acquire()
    finally:
        with _count_lock:
            _waiting -= 1
    try:
        yield
    finally:
        RENDER_LOCK.release()


def frames_waiting() -> bool:
    """Whether a frame of some session waits for its turn."""
    return _waiting > 0
