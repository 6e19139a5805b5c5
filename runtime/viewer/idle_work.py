"""What the viewer's render thread does when no frame is wanted: the light volumes' margins.

A resting view's preview (and "marched" neural) frames read the scene's light volumes, and the next small camera move
reads cells just beside the ones they filled; a fill of those cells in the first frame after the move makes that
frame wait (at 256^3, ~3x longer than with them filled: bench/README.md, ray marcher, "idle time").
:func:`fill_light_margins` fills them between changes instead
(:func:`photon_fields.runtime.transport.light_volume.fill_margin`), giving up as soon as a frame is wanted again.
The images do not change (a cell's value is its own); later frames only find more cells filled.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

from photon_fields.runtime.transport.light_volume import fill_margin
from photon_fields.runtime.viewer.render_turns import RENDER_LOCK, frames_waiting

if TYPE_CHECKING:
    from photon_fields.runtime.viewer.session import ViewerSession


def fill_light_margins(session: ViewerSession, stop: threading.Event) -> bool:
    """Fill the margins of the light volumes of the session's scene and of its volume's coarser levels (the first
    frames after changes march those), and what an earlier, stopped call left marked; on the render thread (whose
    scene it is), between frames, in the sessions' render turn (:mod:`photon_fields.runtime.viewer.render_turns`;
    not at all while another page's frame renders). Stops between chunks once ``stop`` is set, the session wants a
    frame or another page's frame waits. True when everything is filled (or there was nothing to fill)."""

    def cancel() -> bool:
        if stop.is_set() or frames_waiting():
            return True
        with session.lock:
            return session.wants_frame()

    if stop.is_set():  # the page went away: no marks for a fill that would stop before its first chunk
        return False
    scenes = [session.scene, *session.scene.shared_cache("levels").values()]  # the full volume and its levels
    work = [(scene, lv) for scene in scenes for lv in scene.shared_cache("light_volumes").values()
            if lv.margin.any() or lv.wanted.any()]
    if not work:
        return True
    if not RENDER_LOCK.acquire(blocking=False):  # another page's frame renders: its turn first, ours next time
        return False
    try:
        for scene, lv in work:
            kind, vec, _ = scene.packed_lights()
            if not fill_margin(scene.medium(), kind, vec, lv, cancel):  # built: its light volumes were filled from it
                return False
        return True
    finally:
        RENDER_LOCK.release()
