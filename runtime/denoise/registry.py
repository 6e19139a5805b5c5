"""The denoisers ``pfn-render --denoise NAME`` offers, in one table: adding one is its module plus one entry here.

A denoiser works on single images (``still``: every image alone, e.g. OIDN) or on frame sequences
(``sequence``: frames of one camera path in order, e.g. the temporal WRLS filter for ``--orbit``), or both. A
still denoiser's function is called as::

    denoise(color, *, threads, what) -> (H, W, 3) float32

with the renderer's L ((H, W, 3) float32), the ``--threads`` value (None: all cores) and ``what``, the text its
one-line errors name (``--denoise NAME``). A sequence denoiser's factory is called once per sequence as
``factory(scene)`` and returns an object with ``reset()`` and ``denoise(frame, camera=camera)`` (the frames in
order, each with its camera; see :class:`photon_fields.runtime.denoise.wrls.WRLSDenoiser`).
``check``, if given, is called before anything is rendered and raises the one-line error of a denoiser that cannot
run here (an optional package not installed). Functions are imported on first use, so building the command line
never imports a denoiser's dependencies.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from importlib import metadata
from typing import Any


def _load(target: str) -> Callable[..., Any]:
    module, name = target.split(":")
    return getattr(importlib.import_module(module), name)


@dataclass(frozen=True)
class Denoiser:
    """One entry of :data:`DENOISERS`."""

    name: str
    """``--denoise`` value."""
    summary: str
    """What it is and needs, for ``--help``."""
    still: str | None = None
    """``module:function`` of the still-image denoise function (imported on first use), or None."""
    sequence: str | None = None
    """``module:factory`` making the denoiser of one frame sequence (``--orbit``) from the scene, or None."""
    check: str | None = None
    """``module:function(what)`` raising the one-line error when it cannot run here, or None."""
    package: str | None = None
    """The distribution it runs on (its version goes in the render report), or None."""

    @property
    def stills(self) -> bool:
        """Denoises single images."""
        return self.still is not None

    @property
    def sequences(self) -> bool:
        """Denoises frame sequences."""
        return self.sequence is not None

    def denoise_function(self) -> Callable[..., Any]:
        """The still-image denoise function itself."""
        if self.still is None:
            raise ValueError(f"denoiser {self.name} denoises frame sequences, not single images")
        return _load(self.still)

    def sequence_denoiser(self, scene: Any) -> Any:
        """A new denoiser for one frame sequence of ``scene`` (its camera's size, its medium for depth maps)."""
        if self.sequence is None:
            raise ValueError(f"denoiser {self.name} denoises single images, not frame sequences")
        return _load(self.sequence)(scene)

    def check_available(self, what: str) -> None:
        """Refuse, in one line naming ``what``, a denoiser that cannot run on this machine."""
        if self.check is not None:
            _load(self.check)(what)

    def version(self) -> str | None:
        """The installed version of :attr:`package` (None: no package, or not installed)."""
        if self.package is None:
            return None
        try:
            return metadata.version(self.package)
        except metadata.PackageNotFoundError:
            return None


DENOISERS: dict[str, Denoiser] = {d.name: d for d in (
    Denoiser("oidn", "Intel Open Image Denoise on the final image L, each image alone (the optional extra: "
             "pip install 'photon-fields[oidn]')", still="photon_fields.runtime.denoise.oidn:denoise_oidn",
             check="photon_fields.runtime.denoise.oidn:require_oidn", package="pyoidn"),
    Denoiser("wrls", "the temporal WRLS denoiser (paper 002) on the frames of an --orbit, in order, each reprojected "
             "into the next view; every frame then gets its own seed (--seed + frame index)",
             sequence="photon_fields.runtime.denoise.wrls:for_scene"),
)}

#: The ``--denoise`` choices, in the table's order.
DENOISER_NAMES: tuple[str, ...] = tuple(DENOISERS)
