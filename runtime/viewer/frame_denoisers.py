"""The viewer's WRLS denoisers, one per frame size (full, and reduced while moving), sharing one depth estimator.

A session renders at two sizes (reduced frames while the camera moves, full ones at rest); each size needs a
:class:`photon_fields.runtime.denoise.wrls.WRLSDenoiser` of its own, whose temporal history is only valid for the
frames it has seen. :class:`FrameDenoisers` keeps them: a cut (a change that is not a camera move) resets them all,
a switch of frame size resets the one switched to (its history is from before the switch), and a transfer-function
edit (another medium) drops them and their depth estimator.
"""

from __future__ import annotations

from typing import Any

from photon_fields.runtime.scene.scene import Scene


class FrameDenoisers:
    """WRLS denoisers by frame size (module docstring); used by the session's render thread only."""

    def __init__(self) -> None:
        self._by_size: dict[tuple[int, int], Any] = {}
        self._depth: Any = None  # the denoisers' shared DepthEstimator (of the medium in use)
        self._last_size: tuple[int, int] = (0, 0)

    @property
    def depth(self) -> Any:
        """The depth estimator the denoisers share (None until the first frame of a medium)."""
        return self._depth

    def __len__(self) -> int:
        return len(self._by_size)

    def values(self) -> list[Any]:
        """The denoisers kept (at most two: full size and the last reduced size)."""
        return list(self._by_size.values())

    def forget_medium(self) -> None:
        """The medium changed: the depth estimator and every denoiser built on it go."""
        self._depth, self._by_size = None, {}

    def for_frame(self, scene: Scene, size: tuple[int, int], full: tuple[int, int], cut: bool) -> Any:
        """The denoiser for a frame of ``size`` (``full``: the resting size, whose denoiser is kept too) of
        ``scene``; ``cut``: the frame starts a new history."""
        if cut:
            for d in self._by_size.values():
                d.reset()
        denoiser = self._by_size.get(size)
        if denoiser is None:
            from photon_fields.runtime.denoise.depth import DepthEstimator
            from photon_fields.runtime.denoise.wrls import WRLSDenoiser

            if self._depth is None:  # one for every frame size: building it takes tens of ms
                self._depth = DepthEstimator(scene.medium())
            denoiser = WRLSDenoiser(*size, depth_estimator=self._depth)
            self._by_size = {k: v for k, v in self._by_size.items() if k in (full, size)} | {size: denoiser}
        elif size != self._last_size:
            denoiser.reset()  # its history is from before the last change of frame size: stale
        self._last_size = size
        return denoiser
