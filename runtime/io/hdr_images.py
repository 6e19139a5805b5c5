"""High-dynamic-range images for environment lights: OpenEXR (``.exr``) and Radiance RGBE (``.hdr``).

:func:`read_environment_image` is the one entry point: a float RGB image ``(H, W, 3)`` float32, validated for
use as an equirectangular environment map (W = 2 H, every pixel finite and >= 0), or a one-line
:class:`photon_fields.runtime.errors.InputError`:

- ``.exr``: read with :func:`photon_fields.runtime.io.images.read_exr_planes`; the channels must be float
  (half or float, not uint). RGB is taken from bare ``R``, ``G``, ``B`` channels, or from the only
  ``<layer>.R/G/B`` triple (``L`` when there are several, as in this project's renders), or from a single
  grey channel (``Y``) repeated.
- ``.hdr`` / ``.pic``: Radiance RGBE (Greg Ward, "Real Pixels", Graphics Gems II, 1991), read here on numpy (no
  image package in the runtime reads it): the text header (``#?RADIANCE`` or ``#?RGBE``, ``FORMAT=32-bit_rle_rgbe``,
  an optional ``EXPOSURE``), the resolution line ``-Y H +X W`` (the standard orientation; others are refused),
  then scanlines either flat (4 bytes per pixel) or in the "new" run-length encoding (each scanline starts
  with ``2 2 W_hi W_lo``; then per component runs: a count byte > 128 repeats the next byte count - 128
  times, otherwise count literal bytes follow). A pixel is ``(r, g, b) * 2^(e - 136)`` (0 when e = 0).
  ``EXPOSURE`` divides the values back (the header records how much they were scaled by).

:func:`write_radiance_hdr` writes flat (uncompressed) or run-length-encoded RGBE files, for tests and tools.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.io.atomic import atomic_path
from photon_fields.runtime.io.images import read_exr_planes

PathLike = str | os.PathLike[str]

#: File name endings of the formats read by :func:`read_environment_image`.
HDR_SUFFIXES = (".exr", ".hdr", ".pic")
_RESOLUTION = re.compile(rb"^-Y (\d+) \+X (\d+)$")
_MAX_SIDE = 1 << 15


def _rgbe_to_float(rgbe: np.ndarray) -> np.ndarray:
    """(..., 4) uint8 RGBE -> (..., 3) float32 (Ward's decoding: mantissa + 0.5 is not used, as in Radiance's
    ``colr_color`` of the original release and most readers: (m / 256) 2^(e - 128))."""
    e = rgbe[..., 3].astype(np.int32)
    scale = np.where(e > 0, np.ldexp(1.0, e - 136), 0.0).astype(np.float32)
    return rgbe[..., :3].astype(np.float32) * scale[..., None]


def _float_to_rgbe(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) float >= 0 -> (..., 4) uint8 RGBE (the largest component's exponent, mantissas truncated)."""
    m = np.max(rgb, axis=-1)
    mant, e = np.frexp(m)  # m = mant 2^e, mant in [0.5, 1)
    ok = m >= 1e-32
    scale = np.where(ok, mant * 256.0 / np.where(ok, m, 1.0), 0.0)
    out = np.zeros(rgb.shape[:-1] + (4,), dtype=np.uint8)
    out[..., :3] = np.where(ok[..., None], np.floor(rgb * scale[..., None]), 0).clip(0, 255).astype(np.uint8)
    out[..., 3] = np.where(ok, e + 128, 0).astype(np.uint8)
    return out


def _decode_rle(data: bytes, pos: int, width: int, what: str, row: int) -> tuple[np.ndarray, int]:
    """One new-style run-length-encoded scanline at ``pos`` (after its 4-byte marker): ((W, 4) uint8, new pos)."""
    line = np.empty((4, width), dtype=np.uint8)
    for c in range(4):
        x = 0
        while x < width:
            if pos >= len(data):
                raise InputError(what, f"truncated Radiance HDR file (scanline {row})")
            count = data[pos]
            pos += 1
            if count > 128:  # a run
                count -= 128
                if count > width - x or pos >= len(data):
                    raise InputError(what, f"corrupt Radiance HDR run-length data (scanline {row})")
                line[c, x:x + count] = data[pos]
                pos += 1
            else:  # literal bytes
                if count == 0 or count > width - x or pos + count > len(data):
                    raise InputError(what, f"corrupt Radiance HDR run-length data (scanline {row})")
                line[c, x:x + count] = np.frombuffer(data, np.uint8, count, pos)
                pos += count
            x += count
    return line.T, pos


def read_radiance_hdr(path: PathLike) -> np.ndarray:
    """A Radiance RGBE file as (H, W, 3) float32 (module docstring); one-line InputError on any problem."""
    p = Path(path)
    what = str(p)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise InputError(what, "file not found") from None
    except OSError as exc:
        raise InputError(what, f"cannot read file ({exc.strerror or exc})") from None
    if not (data.startswith(b"#?RADIANCE") or data.startswith(b"#?RGBE")):
        raise InputError(what, "not a Radiance HDR file (it must start with '#?RADIANCE' or '#?RGBE')")
    end = data.find(b"\n\n")
    if end < 0:
        raise InputError(what, "truncated Radiance HDR header (no blank line after it)")
    exposure = 1.0
    for line in data[:end].split(b"\n")[1:]:
        if line.startswith(b"FORMAT=") and line.strip() != b"FORMAT=32-bit_rle_rgbe":
            raise InputError(what, f"unsupported Radiance format {line[7:].decode(errors='replace')!r} "
                             "(only 32-bit_rle_rgbe)")
        if line.startswith(b"EXPOSURE="):
            try:
                exposure *= float(line[9:])
            except ValueError:
                raise InputError(what, "bad EXPOSURE line in the Radiance HDR header") from None
    nl = data.find(b"\n", end + 2)
    match = _RESOLUTION.match(data[end + 2:nl if nl >= 0 else len(data)].strip())
    if match is None:
        raise InputError(what, "unsupported Radiance HDR resolution line (only the standard '-Y H +X W')")
    h, w = int(match.group(1)), int(match.group(2))
    if not (1 <= h <= _MAX_SIDE and 1 <= w <= _MAX_SIDE):
        raise InputError(what, f"implausible Radiance HDR size {w}x{h}")
    pos = nl + 1
    rgbe = np.empty((h, w, 4), dtype=np.uint8)
    for y in range(h):
        head = data[pos:pos + 4]
        if 8 <= w < 0x8000 and len(head) == 4 and head[0] == 2 and head[1] == 2 and head[2] < 128:
            if (head[2] << 8 | head[3]) != w:
                raise InputError(what, f"corrupt Radiance HDR file (scanline {y} has the wrong width)")
            rgbe[y], pos = _decode_rle(data, pos + 4, w, what, y)
        else:  # flat pixels (old-style run-length encoding is not supported: it is refused as truncated/corrupt)
            if pos + 4 * w > len(data):
                raise InputError(what, f"truncated Radiance HDR file (scanline {y})")
            rgbe[y] = np.frombuffer(data, np.uint8, 4 * w, pos).reshape(w, 4)
            pos += 4 * w
    return _rgbe_to_float(rgbe) / np.float32(exposure)


def write_radiance_hdr(path: PathLike, rgb: np.ndarray, rle: bool = True) -> Path:
    """Write (H, W, 3) radiance >= 0 as a Radiance RGBE file, run-length encoded (``rle``, for 8 <= W < 32768) or
    flat, atomically."""
    rgb = np.asarray(rgb, dtype=np.float64)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"rgb must be (H, W, 3), got {rgb.shape}")
    h, w = rgb.shape[:2]
    rgbe = _float_to_rgbe(np.maximum(rgb, 0.0))
    out = bytearray(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {h} +X {w}\n".encode())
    for y in range(h):
        if not (rle and 8 <= w < 0x8000):
            out += rgbe[y].tobytes()
            continue
        out += bytes([2, 2, w >> 8, w & 255])
        for c in range(4):
            comp = rgbe[y, :, c]
            x = 0
            while x < w:  # a run of >= 3 equal bytes as a run, the rest as literals (at most 127 / 128 each)
                run = 1
                while x + run < w and run < 127 and comp[x + run] == comp[x]:
                    run += 1
                if run >= 3:
                    out += bytes([128 + run, int(comp[x])])
                    x += run
                    continue
                n = min(128, w - x)
                out += bytes([n]) + comp[x:x + n].tobytes()
                x += n
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(target) as tmp:
        Path(tmp).write_bytes(bytes(out))
    return target


def _exr_rgb(path: Path) -> np.ndarray:
    what = str(path)
    planes, _ = read_exr_planes(path)
    not_float = sorted(k for k, v in planes.items() if not np.issubdtype(v.dtype, np.floating))
    if not_float:
        raise InputError(what, f"not a float image: channel {not_float[0]!r} holds integers (an environment map "
                         "needs half or float channels)")
    if all(c in planes for c in "RGB"):
        return np.stack([planes[c] for c in "RGB"], axis=-1)
    layers = sorted({k.rpartition(".")[0] for k in planes if k.endswith(".R")
                     and all(f"{k[:-2]}.{c}" in planes for c in "GB")})
    if len(layers) > 1 and "L" in layers:
        layers = ["L"]
    if len(layers) == 1:
        return np.stack([planes[f"{layers[0]}.{c}"] for c in "RGB"], axis=-1)
    if len(layers) > 1:
        raise InputError(what, f"several RGB layers ({', '.join(layers)}): cannot tell which is the environment")
    grey = [k for k in planes if k == "Y" or k.endswith(".Y")]
    if len(grey) == 1:
        return np.repeat(planes[grey[0]][..., None], 3, axis=-1)
    raise InputError(what, f"no RGB (or single grey) channels to use as an environment map "
                     f"(channels: {', '.join(sorted(planes)) or 'none'})")


def read_environment_image(path: PathLike) -> np.ndarray:
    """An equirectangular environment image as (H, W, 3) float32, validated (module docstring)."""
    p = Path(path)
    what = str(p)
    suffix = p.suffix.lower()
    if suffix not in HDR_SUFFIXES:
        raise InputError(what, f"not an HDR image: an environment map must be a float image, "
                         f"{' or '.join(HDR_SUFFIXES[:2])} (got {suffix or 'no suffix'!r})")
    if not p.exists():
        raise InputError(what, "file not found")
    if not p.is_file():
        raise InputError(what, "is not a regular file")
    rgb = _exr_rgb(p) if suffix == ".exr" else read_radiance_hdr(p)
    rgb = np.ascontiguousarray(rgb, dtype=np.float32)
    h, w = rgb.shape[:2]
    if w != 2 * h:
        raise InputError(what, f"an equirectangular environment map must be twice as wide as high, got {w}x{h}")
    bad = ~np.isfinite(rgb)
    if bad.any():
        y, x, _ = np.argwhere(bad)[0]
        raise InputError(what, f"{int(bad.any(axis=-1).sum())} pixels are NaN or infinite (first at row {y}, "
                         f"column {x})")
    if (rgb < 0).any():
        y, x, _ = np.argwhere(rgb < 0)[0]
        raise InputError(what, f"{int((rgb < 0).any(axis=-1).sum())} pixels are negative (first at row {y}, "
                         f"column {x}): radiance must be >= 0")
    return rgb
