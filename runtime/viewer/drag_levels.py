"""What makes a frame of a changing view cheaper: the sizes of moving frames under ``drag_scale="auto"`` (a fraction
of the view chosen after every moving frame so that dragging keeps :data:`DRAG_FPS` frames per second), and the
volume level the preview marches for the first frame of every change (the session's docstring says how both are
used)."""

from __future__ import annotations

from photon_fields.runtime.scene.levels import check_level, interactive_level

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


def changing_level(setting: int | str, renderer: str, dims: tuple[int, ...]) -> int:
    """The volume level (:mod:`photon_fields.runtime.scene.levels`) of the first frame after a change (a camera
    move or an edit) with ``renderer`` (a page name): ``setting`` ``"auto"``: :func:`interactive_level` of the
    volume's ``dims``, an int: that level. 0 for every renderer but the marching ones (the preview, and with the
    field's L_i): the others' frames cost hardly more on a finer volume (bench/README.md)."""
    if renderer not in ("preview", "marched"):
        return 0
    return interactive_level(dims) if setting == "auto" else check_level(setting)  # type: ignore[arg-type]
