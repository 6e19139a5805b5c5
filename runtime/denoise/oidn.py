"""Intel Open Image Denoise (OIDN) for still images: the denoiser a user would put after a path tracer, so the
one the neural renderer is compared with (bench/bench_equal_error.py), and ``pfn-render --denoise oidn``.

OIDN is a trained convolutional network (Apache-2.0, CPU here) reached through the ``pyoidn`` binding, an
optional extra because its wheel is ~170 MB: ``pip install 'photon-fields[oidn]'``. Nothing imports ``pyoidn``
until an image is denoised, so the renderers work without it; asking for OIDN without it is one line
(:func:`require_oidn`).

What is denoised: linear HDR radiance, (H, W, 3) float32, non-negative (the ``hdr`` mode of OIDN's "RT"
filter). An optional ``albedo`` (H, W, 3) in [0, 1] is OIDN's auxiliary feature image. The renderers give
none: a first-interaction albedo of the same samples made OIDN's error worse on most builtin scenes, and a
noise-free one pays on vortex only, and there no more than the same time spent on samples (docs/rendering.md,
bench/bench_oidn.py).

One OIDN device and filter per thread count are created on first use and kept for the process: the first
call of a process costs ~40 ms more at 256x256 (and importing pyoidn ~1.4 s, once). The output is a function
of the input alone: the same image gives the same bytes, for any thread count (tests/runtime/denoise/test_oidn.py).
"""

from __future__ import annotations

import threading
from importlib import metadata
from types import ModuleType
from typing import Any

import numpy as np

from photon_fields.runtime.errors import InputError

#: The denoiser's name in the registry (:mod:`photon_fields.runtime.denoise.registry`) and in messages.
NAME = "oidn"
#: How to get it: the optional extra of this package.
INSTALL = "pip install 'photon-fields[oidn]'"
#: Oldest pyoidn whose filter setters work (2.3.x passes the device handle to oidnSetFilterBool, so HDR
#: could not be switched on); the extra in pyproject.toml asks for the same.
MIN_VERSION = (2, 5)
QUALITIES = ("high", "balanced", "fast")

_lock = threading.Lock()
_filters: dict[int, tuple[Any, Any]] = {}  # threads (0: all cores) -> (device, filter), kept for the process


def _version_tuple(text: str) -> tuple[int, ...]:
    parts = []
    for p in text.split("."):
        if not p.isdigit():
            break
        parts.append(int(p))
    return tuple(parts)


def require_oidn(what: str = f"denoiser {NAME}") -> ModuleType:
    """The ``pyoidn`` module, or one line naming ``what`` asked for it and how to install it (InputError):
    not installed, too old, or its native library does not load on this machine."""
    try:
        import pyoidn
    except ImportError:
        raise InputError(what, f"needs Intel Open Image Denoise (the optional package pyoidn, ~170 MB), which is "
                               f"not installed: {INSTALL}") from None
    except OSError as exc:  # the wheel's shared libraries failed to load
        raise InputError(what, f"pyoidn is installed but its native library does not load ({exc}); reinstall "
                               f"it: {INSTALL}") from None
    try:
        version = metadata.version("pyoidn")
    except metadata.PackageNotFoundError:  # imported from a source tree: trust it
        version = None
    if version is not None and _version_tuple(version) < MIN_VERSION:
        raise InputError(what, f"pyoidn {version} is too old (need >= {'.'.join(map(str, MIN_VERSION))}): "
                               f"{INSTALL} --upgrade")
    return pyoidn


def oidn_available() -> bool:
    """Whether :func:`denoise_oidn` can run here (pyoidn installed, recent enough, loadable)."""
    try:
        require_oidn()
    except InputError:
        return False
    return True


def oidn_version() -> str | None:
    """The installed pyoidn version (its OIDN library's version plus a binding number), or None."""
    try:
        return metadata.version("pyoidn")
    except metadata.PackageNotFoundError:
        return None


def check_image(image: Any, role: str, what: str, shape: tuple[int, ...] | None = None,
                unit_range: bool = False) -> np.ndarray:
    """``image`` as a C-contiguous (H, W, 3) float32 array, or one line (InputError) naming ``what`` (the
    denoiser) and the ``role`` of the image: wrong shape, another size than ``shape``, not real numbers,
    non-finite pixels (OIDN would spread them over their neighbourhood), negative values, or (``unit_range``)
    values outside [0, 1]."""
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise InputError(what, f"{role} must be an (H, W, 3) RGB image, got shape {arr.shape}")
    if shape is not None and arr.shape != shape:
        raise InputError(what, f"{role} is {arr.shape[1]}x{arr.shape[0]} but the colour image "
                               f"{shape[1]}x{shape[0]}: every image of one denoise call has the same size")
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise InputError(what, f"{role} must hold real numbers, got dtype {arr.dtype}")
    arr = np.ascontiguousarray(arr, dtype=np.float32)
    finite = np.isfinite(arr)
    if not finite.all():
        bad = int((~finite.all(axis=2)).sum())
        raise InputError(what, f"{role} has {bad} pixel(s) with NaN or infinite values")
    low = float(arr.min())
    if low < 0.0:
        raise InputError(what, f"{role} has negative values (min {low:g}); radiance must be >= 0")
    if unit_range and float(arr.max()) > 1.0:
        raise InputError(what, f"{role} must be in [0, 1], got values up to {float(arr.max()):g}")
    return arr


def _filter(pyoidn: ModuleType, threads: int) -> Any:
    """The process's OIDN filter for ``threads`` (0: all cores), created on first use (with its device)."""
    if threads not in _filters:
        device = pyoidn.Device(pyoidn.OIDN_DEVICE_TYPE_CPU)
        if threads:
            device.set_int("numThreads", threads)
        device.commit()
        error = device.get_error()
        if error is not None:
            device.release()
            raise RuntimeError(f"OIDN: cannot create a CPU device: {error}")
        _filters[threads] = (device, pyoidn.Filter(device, pyoidn.OIDN_FILTER_TYPE_RT))
    return _filters[threads]


def denoise_oidn(color: Any, albedo: Any | None = None, *, threads: int | None = None, quality: str = "high",
                 what: str = f"denoiser {NAME}") -> np.ndarray:
    """Denoise the linear HDR image ``color`` (H, W, 3), with ``albedo`` (H, W, 3) in [0, 1] as the auxiliary
    feature if given; returns a new (H, W, 3) float32 image, a function of the inputs alone.

    ``threads``: OIDN's worker threads (None or 0: all cores; the caller's ``--threads``). ``quality``: one of
    :data:`QUALITIES` ("balanced" took as long as "high" here; "fast" half the time, for 5-10 % more error,
    bench/README.md).
    Bad input (shape, size, dtype, non-finite or negative values, pyoidn missing) raises a one-line InputError
    naming ``what``; a failure inside OIDN raises RuntimeError with its message."""
    if quality not in QUALITIES:
        raise InputError(what, f"quality must be one of {', '.join(QUALITIES)}, got {quality!r}")
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 0):
        raise InputError(what, f"threads must be a non-negative integer (0: all cores), got {threads!r}")
    colour = check_image(color, "colour image", what)
    aux = None if albedo is None else check_image(albedo, "albedo image", what, colour.shape, unit_range=True)
    pyoidn = require_oidn(what)
    output = np.empty_like(colour)
    fmt = pyoidn.OIDN_FORMAT_FLOAT3
    with _lock:  # one filter per thread count, configured call by call
        device, flt = _filter(pyoidn, threads or 0)
        flt.set_image(pyoidn.OIDN_IMAGE_COLOR, colour, fmt)
        if aux is not None:
            flt.set_image(pyoidn.OIDN_IMAGE_ALBEDO, aux, fmt)
        else:
            flt.unset_image(pyoidn.OIDN_IMAGE_ALBEDO)
        flt.set_image(pyoidn.OIDN_IMAGE_OUTPUT, output, fmt)
        flt.set_bool("hdr", True)
        flt.set_int("quality", {"high": pyoidn.OIDN_QUALITY_HIGH, "balanced": pyoidn.OIDN_QUALITY_BALANCED,
                                "fast": pyoidn.OIDN_QUALITY_FAST}[quality])
        flt.commit()
        flt.execute()
        error = device.get_error()
        # The filter keeps pointers to these arrays: drop them so a later call cannot read freed memory.
        for name in (pyoidn.OIDN_IMAGE_COLOR, pyoidn.OIDN_IMAGE_ALBEDO, pyoidn.OIDN_IMAGE_OUTPUT):
            flt.unset_image(name)
        if error is not None:  # start afresh next time: a failed filter's state is unknown
            flt.release()
            device.release()
            del _filters[threads or 0]
            raise RuntimeError(f"OIDN failed: {error}")
    return output
