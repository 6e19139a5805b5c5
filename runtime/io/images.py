"""Image output: multi-layer float OpenEXR files and tonemapped 8-bit PNG previews.

Conventions
-----------
- Images are numpy arrays indexed ``[row, column]`` with row 0 at the top (the camera's ``py = 0``).
  A *layer* is either RGB, shape ``(H, W, 3)``, or single-channel, shape ``(H, W)``; every layer of
  one file has the same ``(H, W)``. Pixel values are linear radiance in Rec.709/sRGB primaries.
- EXR files are scanline, ZIP-compressed, float32. Layer ``L`` (RGB) is stored as channels ``L.R``,
  ``L.G``, ``L.B``; a single-channel layer ``D`` as ``D.Y``. Inputs are cast to float32 (float64
  data is rounded). Non-finite pixels (NaN/inf) are written as they are: the EXR is the faithful
  record, and only the PNG preview has to cope with them.
- ``metadata`` is a ``dict[str, str]`` stored as string attributes of the EXR header (any text,
  including newlines). Names of the standard header attributes (``channels``, ``compression`` ...)
  are refused so that metadata cannot corrupt the header.
- Every file is written atomically via :func:`photon_fields.runtime.io.atomic.atomic_path` (an interrupted or failed
  write leaves any previous file intact); missing parent directories are created. A failure to
  read or write a file is raised as :class:`photon_fields.runtime.errors.InputError` with a one-line message, since
  paths come from the user; malformed arrays are programming errors and raise ``ValueError``.

Tonemapping (:func:`tonemap_srgb`), in this order:

1. exposure: multiply by ``2**exposure`` (stops), or, when ``exposure`` is None, by the factor that
   maps the 99.5th percentile of the luminance (Rec.709 weights) of the finite pixels to 1.0. If that
   percentile is 0 (fewer than 0.5 % lit pixels) the maximum is used instead; an all-black image
   stays black. Scaling the input therefore never changes an auto-exposed PNG.
2. tone curve: the ACES filmic curve as fitted by K. Narkowicz (2015), per channel,
   ``f(x) = x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14)`` clipped to [0, 1]. It has a gentle toe
   and a long shoulder: ``f(1) = 0.80``, so auto exposure puts the 99.5th percentile at about 230/255
   and leaves headroom for highlights, which reach white at ``x = 7.24``. Negative values become 0.
3. the exact piecewise sRGB OETF (:func:`srgb_oetf`), then rounding to uint8. Pixels with any
   non-finite channel become black (0, 0, 0).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import OpenEXR
from PIL import Image

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.io.atomic import atomic_path

__all__ = [
    "aces_fitted",
    "read_exr",
    "read_exr_planes",
    "srgb_oetf",
    "tonemap_srgb",
    "auto_exposure_stops",
    "write_exr",
    "write_image_set",
    "write_png",
]

PathLike = str | os.PathLike[str]

_RGB = ("R", "G", "B")
_EXR_MAGIC = b"\x76\x2f\x31\x01"
# Header attributes OpenEXR defines itself (required or standard): metadata must not shadow them.
_RESERVED_ATTRIBUTES = frozenset(
    {
        "channels",
        "compression",
        "dataWindow",
        "displayWindow",
        "lineOrder",
        "pixelAspectRatio",
        "screenWindowCenter",
        "screenWindowWidth",
        "type",
        "name",
        "tiles",
        "version",
        "chunkCount",
        "view",
    }
)
_LUMA = np.array([0.2126, 0.7152, 0.0722])  # Rec.709 luminance weights (linear sRGB primaries)
_MAX_STOPS = 1000.0  # 2**1000 is still a finite float64; larger exposures would raise OverflowError
_MAX_SCALE = 2.0**_MAX_STOPS
CURVE_WHITE = 16.0  # aces_fitted reaches 1.0 at 7.24, so clipping above that changes nothing


# ----------------------------------------------------------------------------------------------
# EXR
# ----------------------------------------------------------------------------------------------


def _exr_channels(layers: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Validate layers and split them into contiguous float32 channel planes named ``<layer>.<c>``."""
    if not layers:
        raise ValueError("write_exr needs at least one layer")
    channels: dict[str, np.ndarray] = {}
    size: tuple[int, int] | None = None
    for name, data in layers.items():
        if not isinstance(name, str) or not name:
            raise ValueError(f"layer names must be non-empty strings, got {name!r}")
        arr = np.asarray(data)
        if not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] == 3)):
            raise ValueError(f"layer {name!r}: expected shape (H, W, 3) or (H, W), got {arr.shape}")
        if arr.shape[0] < 1 or arr.shape[1] < 1:
            raise ValueError(f"layer {name!r}: empty image of shape {arr.shape}")
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
            raise ValueError(f"layer {name!r}: expected real numbers, got dtype {arr.dtype}")
        if size is None:
            size = arr.shape[:2]
        elif arr.shape[:2] != size:
            raise ValueError(f"layer {name!r}: size {arr.shape[:2]} differs from the first layer's {size}")
        arr = arr.astype(np.float32, copy=False)
        planes = {"Y": arr} if arr.ndim == 2 else {c: arr[:, :, i] for i, c in enumerate(_RGB)}
        for c, plane in planes.items():
            key = f"{name}.{c}"
            if key in channels:
                raise ValueError(f"layer {name!r}: channel name {key!r} is produced twice")
            channels[key] = np.ascontiguousarray(plane)
    return channels


def _check_metadata(metadata: Mapping[str, str] | None) -> dict[str, str]:
    out: dict[str, str] = {}
    for key, value in (metadata or {}).items():
        if not isinstance(key, str) or not key:
            raise ValueError(f"metadata keys must be non-empty strings, got {key!r}")
        if key in _RESERVED_ATTRIBUTES:
            raise ValueError(f"metadata key {key!r} is a reserved OpenEXR header attribute")
        if not isinstance(value, str):
            raise TypeError(f"metadata {key!r}: values must be str, got {type(value).__name__}")
        out[key] = value
    return out


def _prepare_output(path: PathLike) -> Path:
    target = Path(path)
    if target.is_dir():
        raise InputError(str(target), "is a directory, not an output file")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(str(target), f"cannot create the output directory: {exc.strerror or exc}") from exc
    return target


def write_exr(
    path: PathLike, layers: Mapping[str, np.ndarray], metadata: Mapping[str, str] | None = None
) -> Path:
    """Write ``layers`` (name -> (H, W, 3) or (H, W) array) and string ``metadata`` to an EXR file.

    See the module docstring for the channel naming. Returns the path written.
    """
    channels = _exr_channels(layers)
    header: dict[str, object] = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    header.update(_check_metadata(metadata))
    target = _prepare_output(path)
    try:
        with atomic_path(target) as tmp:
            OpenEXR.File(header, channels).write(str(tmp))
    except (OSError, RuntimeError) as exc:  # OpenEXR reports I/O failures as RuntimeError
        raise InputError(str(target), f"cannot write OpenEXR file: {exc}") from exc
    return target


def _regroup(planes: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], str | None]:
    """Channel planes -> ``(layers, clash)``.

    Complete ``<l>.R/G/B`` triples become (H, W, 3) layers and ``<l>.Y`` a (H, W) layer; any other
    channel (files from other tools: bare ``R``, ``A``, ``Z`` ...) is kept as a single-channel layer
    under its full channel name. ``clash`` names a channel that cannot be given a distinct layer name
    (e.g. a bare channel ``L`` next to ``L.R/G/B``), which the caller reports.
    """
    split = {key: key.rpartition(".") for key in planes}
    rgb = {layer for layer, _, c in split.values() if layer and c == "R"}
    rgb = {layer for layer in rgb if all(f"{layer}.{k}" in planes for k in _RGB)}
    layers = {layer: np.stack([planes[f"{layer}.{k}"] for k in _RGB], axis=-1) for layer in sorted(rgb)}
    rest = [key for key, (layer, _, c) in split.items() if not (layer in rgb and c in _RGB)]
    for key in sorted(rest, key=lambda k: (split[k][2] != "Y", k)):  # <l>.Y claims its name first
        layer, _, c = split[key]
        name = layer if layer and c == "Y" and layer not in layers and layer not in planes else key
        if name in layers:
            return layers, key
        layers[name] = planes[key]
    return layers, None


def read_exr_planes(path: PathLike) -> tuple[dict[str, np.ndarray], dict[str, object]]:
    """The 2-D channel planes of an EXR's first part as stored (float16, float32 or uint32) and its header:
    ``(planes, header)``. A missing, unreadable or corrupt file raises :class:`InputError`. :func:`read_exr`
    regroups them; the environment-map reader (:mod:`photon_fields.runtime.io.hdr_images`) checks their types."""
    p = Path(path)
    what = str(p)
    if not p.exists():
        raise InputError(what, "file not found")
    if p.is_dir():
        raise InputError(what, "is a directory, not an OpenEXR file")
    try:
        with open(p, "rb") as f:
            magic = f.read(4)
    except OSError as exc:
        raise InputError(what, f"cannot read file: {exc.strerror or exc}") from exc
    if magic != _EXR_MAGIC:
        # Checked here because the library's own message for this case is a misleading "unable to open".
        raise InputError(what, "not an OpenEXR file (bad magic number)")
    try:
        with OpenEXR.File(str(p), separate_channels=True) as exr:
            # A file whose pixel data fails to decode yields no parts (the library only prints a
            # warning), so accessing the first part below raises: both count as corrupt.
            # Copies: leaving the context clears the header and channel dicts the library handed out.
            header = dict(exr.header())
            planes = {name: np.array(ch.pixels, copy=True) for name, ch in exr.channels().items()}
    except (RuntimeError, ValueError, IndexError, OSError) as exc:
        raise InputError(what, "corrupt or truncated OpenEXR file (cannot decode its pixel data)") from exc
    return {k: v for k, v in planes.items() if v.ndim == 2}, header


def read_exr(path: PathLike) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """Read an EXR written by :func:`write_exr` (or another tool): ``(layers, metadata)``.

    Layers are float32 arrays regrouped as described in :func:`_regroup`; metadata holds every string
    attribute of the header (other than the standard ones). Only the first part of a multi-part file
    is read. A missing, unreadable or corrupt file raises :class:`InputError`.
    """
    what = str(Path(path))
    planes, header = read_exr_planes(path)
    planes = {k: v.astype(np.float32, copy=False) for k, v in planes.items()}
    layers, clash = _regroup(planes)
    if clash is not None:
        raise InputError(what, f"channel {clash!r} clashes with a layer of the same name")
    metadata = {k: v for k, v in header.items() if isinstance(v, str) and k not in _RESERVED_ATTRIBUTES}
    return layers, metadata


# ----------------------------------------------------------------------------------------------
# tonemapping and PNG
# ----------------------------------------------------------------------------------------------


def srgb_oetf(x: np.ndarray | float) -> np.ndarray:
    """Exact sRGB encoding (IEC 61966-2-1) of linear values in [0, 1]; inputs are clipped to [0, 1]."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def aces_fitted(x: np.ndarray | float) -> np.ndarray:
    """Narkowicz's fit of the ACES filmic tone curve, per value, clipped to [0, 1] (negatives -> 0)."""
    x = np.maximum(np.asarray(x, dtype=np.float64), 0.0)
    return np.clip(x * (2.51 * x + 0.03) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0)


def auto_exposure_scale(rgb: np.ndarray, finite: np.ndarray) -> float:
    """The automatic exposure factor: the 99.5th percentile of luminance over the ``finite`` pixels maps to 1
    (the brightest pixel when that percentile is black; 1 for an all-black image)."""
    lum = np.maximum(rgb[finite], 0.0) @ _LUMA
    if lum.size == 0:
        return 1.0
    ref = float(np.percentile(lum, 99.5))
    if ref <= 0.0:  # a few lit pixels on black (e.g. fireflies): expose for the brightest one
        ref = float(lum.max())
    return min(1.0 / ref, _MAX_SCALE) if ref > 0.0 else 1.0  # all black stays black


def auto_exposure_stops(rgb: np.ndarray) -> float:
    """The exposure (stops) that automatic exposure would pick for ``rgb`` (H, W, 3): to keep it fixed over
    a sequence of frames, so brightness does not flicker."""
    arr = np.asarray(rgb, dtype=np.float64)
    return float(np.log2(auto_exposure_scale(arr, np.all(np.isfinite(arr), axis=-1))))


def tonemap_srgb(rgb: np.ndarray, exposure: float | None = None) -> np.ndarray:
    """Linear radiance (H, W, 3) (or (H, W), shown grey) -> display sRGB uint8 (H, W, 3).

    ``exposure`` in stops, or None for automatic exposure; see the module docstring for the pipeline.
    """
    arr = np.asarray(rgb, dtype=np.float64)
    if arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) or (H, W) image, got shape {arr.shape}")
    finite = np.all(np.isfinite(arr), axis=2)
    if exposure is None:
        scale = auto_exposure_scale(arr, finite)
    else:
        if not np.isfinite(exposure):
            raise ValueError(f"exposure must be a finite number of stops, got {exposure}")
        scale = 2.0 ** float(np.clip(exposure, -_MAX_STOPS, _MAX_STOPS))
    # Zero non-finite pixels first: NaN or inf must not reach the curve (inf / inf is NaN there).
    arr = np.where(finite[:, :, None], arr, 0.0)
    with np.errstate(over="ignore"):  # huge finite values * scale may overflow to inf: clipped below
        exposed = np.clip(arr * scale, 0.0, CURVE_WHITE)
    encoded = srgb_oetf(aces_fitted(exposed))
    return np.round(encoded * 255.0).astype(np.uint8)


def write_png(path: PathLike, rgb8: np.ndarray) -> Path:
    """Write a uint8 image, (H, W, 3) as RGB or (H, W) as greyscale, to a PNG file atomically."""
    arr = np.asarray(rgb8)
    if arr.dtype != np.uint8:
        raise ValueError(f"write_png expects uint8 pixels, got {arr.dtype} (tonemap first)")
    if not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] == 3)) or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(f"write_png expects an (H, W, 3) or (H, W) image, got shape {arr.shape}")
    image = Image.fromarray(np.ascontiguousarray(arr))  # mode inferred: RGB for (H, W, 3), L for (H, W)
    target = _prepare_output(path)
    try:
        with atomic_path(target) as tmp:
            image.save(tmp, format="PNG")
    except OSError as exc:
        raise InputError(str(target), f"cannot write PNG file: {exc.strerror or exc}") from exc
    return target


def write_image_set(
    exr_path: PathLike,
    layers: Mapping[str, np.ndarray],
    metadata: Mapping[str, str] | None = None,
    png_layer: str = "L",
    exposure: float | None = None,
) -> list[Path]:
    """Write the EXR and, beside it (same stem, ``.png``), a tonemapped PNG preview of ``png_layer``.

    The exposure used (``exposure``, or the automatic one of ``png_layer``) is recorded in the EXR header
    (:data:`EXPOSURE_METADATA`), so the PNG can be reproduced from the EXR and other renders shown alike.
    The preview is computed before anything is written, so a bad ``png_layer`` writes nothing.
    Returns ``[exr_path, png_path]``.
    """
    exr = Path(exr_path)
    png = exr.with_suffix(".png")
    if png == exr:
        raise ValueError(f"the EXR path {exr} must not end in .png (the preview would overwrite it)")
    if png_layer not in layers:
        raise ValueError(f"png_layer {png_layer!r} is not one of the layers {sorted(layers)}")
    stops = resolve_exposure(layers[png_layer], exposure)
    preview = tonemap_srgb(layers[png_layer], stops)
    metadata = {**(metadata or {}), EXPOSURE_METADATA: repr(stops)}
    return [write_exr(exr, layers, metadata), write_png(png, preview)]


#: EXR header attribute holding the exposure (stops) the PNG beside it was tone-mapped with.
EXPOSURE_METADATA = "photon_fields.png_exposure_stops"


def resolve_exposure(rgb: np.ndarray, exposure: float | None) -> float:
    """The exposure (stops) a PNG of ``rgb`` is tone-mapped with: ``exposure`` if given, else the automatic
    one (:func:`auto_exposure_stops`). Resolved once so it can be recorded and reused for other images."""
    return float(exposure) if exposure is not None else auto_exposure_stops(rgb)
