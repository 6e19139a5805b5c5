"""What a viewer page controls (:class:`ViewState`) and what it gets back (:class:`Frame`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from photon_fields.runtime.renderers.registry import CAMERA_OPTION
from photon_fields.runtime.scene.labels import LabelTransfer
from photon_fields.runtime.scene.transfer import TransferFunction
from photon_fields.runtime.viewer.camera import OrbitView
from photon_fields.runtime.viewer.light_control import LightControl
from photon_fields.runtime.viewer.transfer_edit import LabelPanel

DEFAULT_MAX_SPP = 1024


@dataclass
class ViewState:
    """Everything the page controls. Copied (shallowly) for each frame; treat as immutable outside the lock."""

    view: OrbitView
    renderer: str
    layer: str = "L"
    g: float = 0.0
    lights: list[LightControl] = field(default_factory=list)
    exposure_offset: float = 0.0
    format: str = "jpeg"
    denoise: bool = True
    max_spp: int = DEFAULT_MAX_SPP
    width: int = 512
    height: int = 512
    """The frame's size (full size; reduced moving frames are a fraction of it)."""
    view_size: tuple[int, int] | None = None
    """The size of the page's view box in device pixels, as its last ``view`` message said (None: not yet)."""
    drag_scale: float | str = 1.0
    """Moving frames are rendered at this fraction of the size (1: full size); resting frames always full."""
    camera_estimator: str = CAMERA_OPTION.default
    """The neural renderer's camera estimator (``pfn-view --camera-estimator``, then the page's select)."""
    transfer: TransferFunction | LabelTransfer | None = None
    """The transfer function as the page edited it (None: the scene's)."""
    labels: LabelPanel | None = None
    """A label scene's label panel as the page set it (None: a scalar scene, edited with control points)."""


@dataclass
class Frame:
    """One frame for the page: the encoded image and its header (what it shows, how long it took)."""

    image: bytes
    header: dict[str, Any]
