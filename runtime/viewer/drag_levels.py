"""The sizes of moving frames under ``drag_scale="auto"``: a fraction of the view chosen after every moving frame
so that dragging keeps :data:`DRAG_FPS` frames per second (the session's docstring says how it is used)."""

from __future__ import annotations

#: ``drag_scale="auto"``: the sizes moving frames may take (fractions of the view; few, so that each keeps its
#: denoiser's history across drags) and the frame rate they aim at while the camera moves.
DRAG_LEVELS = (1.0, 0.75, 0.5, 0.375, 0.25)
DRAG_FPS = 8.0


def next_drag_level(level: int, frame_s: float, fps: float = DRAG_FPS) -> int:
    """The :data:`DRAG_LEVELS` index for the next moving frame after one at ``level`` took ``frame_s`` seconds:
    one level smaller when it missed the frame time 1 / ``fps`` by more than 15 %, one level larger when the
    larger level's frame (time scaling with the pixel count) would still take at most 85 % of it, else the same."""
    budget = 1.0 / fps
    if frame_s > 1.15 * budget and level + 1 < len(DRAG_LEVELS):
        return level + 1
    if level > 0 and frame_s * (DRAG_LEVELS[level - 1] / DRAG_LEVELS[level]) ** 2 <= 0.85 * budget:
        return level - 1
    return level
