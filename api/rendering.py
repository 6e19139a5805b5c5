"""``photon_fields.render``: a volume in, an :class:`photon_fields.image.Image` out, with no scene file.

It builds a :class:`photon_fields.runtime.scene.scene.Scene` from its arguments (the volume, a transfer function
resolved against it, a named light rig, a camera framing the volume) and renders it with a renderer of
:data:`photon_fields.runtime.renderers.registry.RENDERERS`, loading what that renderer needs: ``field`` a photon
field and ``photonmap`` a photon map, each trained (traced) on first use and cached
(:mod:`photon_fields.field_cache`). Every bad argument is one :class:`InputError` line naming it.
"""

from __future__ import annotations

import inspect
import os
from pathlib import Path
from typing import Any

from photon_fields.image import Image
from photon_fields.runtime.errors import InputError

#: (width, height) of an image when no size is given.
DEFAULT_SIZE = (256, 256)


def render(volume: Any, *, transfer_function: Any = "auto", lights: Any = "studio", method: str = "pt",
           spp: int = 16, size: tuple[int, int] = DEFAULT_SIZE, g: float = 0.0, seed: int = 0,
           spacing: Any = None, camera: Any = None, training: str | dict[str, Any] | None = None,
           cache: str | os.PathLike[str] | None = None, threads: int | None = None, progress: bool = False,
           **options: Any) -> Image:
    """Render ``volume`` with global illumination.

    volume: a numpy array indexed ``[x, y, z]``, a volume file (anything ``load_volume`` reads), a
        ``pyvista.ImageData`` or a :class:`Volume`. ``spacing`` overrides its voxel size (x, y, z).
    transfer_function: ``"auto"`` (from the volume's histogram), a preset name, a TF ``.json`` file (the
        viewer's editor format, :meth:`TransferFunction.save`), a dict in that format, or a TransferFunction.
        For a label (segmentation) volume: ``"labels"`` (each label present its own colour, 0 transparent), a
        dict ``{"labels": {"3": {"albedo": [r, g, b], "opacity": o}, ...}}`` or ``{"preset": "labels",
        "visible": [3, 7]}``, or a :class:`photon_fields.runtime.scene.labels.LabelTransfer`
        (:func:`photon_fields.runtime.scene.labels.labels_transfer` builds one).
    lights: a rig name (:data:`photon_fields.runtime.scene.rigs.LIGHT_RIGS`: studio, sun, sky) or a list of
        light dicts in the scene-file form.
    method: a renderer's name (pt, raymarch, raymarch-field, photonmap, field, pvrt); ``options`` are its own
        settings by keyword (e.g. ``max_depth=4`` for pt, ``camera_estimator="marched"`` for field: less noise
        on sparse media). ``pvrt`` precomputes a PVRT transfer for the volume,
        transfer function and g on first use (cached like a field; ``training`` a dict of ``grid``, ``paths``,
        ``order``, ``basis``, ``exitance_order``, ``clusters``, ``bases``) and relights it with ``lights`` (distant
        lights only). ``field`` trains a photon field on first use (needs the ``train`` extra; ``raymarch-field``,
        the ray marcher with the field's L_i, uses the same cached field), ``photonmap`` traces a photon map, both
        cached in ``cache`` (default ``$PFN_CACHE`` or ``~/.cache/photon-fields``); ``training`` is a trainer
        preset name (default ``cpu``) or a dict of ``preset``, ``photons``, ``steps``, ``batch``, ``k``,
        ``threads``.
    spp, seed: samples per pixel and the random seed (the same seed renders the same image).
    size: (width, height); camera: a camera dict (scene-file form) instead of the framing default.
    g: the phase function's anisotropy in (-1, 1).
    """
    from photon_fields.runtime.cli.common import check_seed
    from photon_fields.runtime.renderers.registry import RENDERERS, int_in
    from photon_fields.runtime.scene.camera import Camera
    from photon_fields.runtime.scene.rigs import framing_camera
    from photon_fields.runtime.scene.scene import Scene
    from photon_fields.runtime.threads import numba_threads
    from photon_fields.runtime.transport.phase import check_g
    from photon_fields.volumes import as_volume

    if method not in RENDERERS:
        raise InputError("method", f"unknown method {method!r} (available: {', '.join(RENDERERS)})")
    renderer = RENDERERS[method]
    known = {_option_name(opt): opt for opt in renderer.options}
    unknown = [k for k in options if k not in known]
    if unknown:
        raise InputError(unknown[0], f"not an option of method {method!r} (its options: "
                                     f"{', '.join(known) or 'none'})")
    options = {k: _option(known[k], k, v) for k, v in options.items()}  # as given (info records them so)
    spp = int_in(1, 1 << 16)("spp", spp)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise InputError("seed", f"must be an integer, got {seed!r}")
    check_seed(seed, "seed")
    width, height = _size(size)
    check_g(g, "g")
    settings = None
    trained = "field" if renderer.input == "bundle" else method  # what the cache holds for it
    if renderer.input == "transfer":
        from photon_fields.field_cache import cache_root, training_settings

        settings = training_settings(training, "pvrt")
        root = cache_root(cache)
    elif renderer.input is not None:
        from photon_fields.field_cache import cache_root, training_settings

        settings = training_settings(training, trained)
        root = cache_root(cache)
    elif training is not None:
        raise InputError("training", f"method {method!r} trains nothing (only "
                                     f"{', '.join(n for n, r in RENDERERS.items() if r.input)} do)")
    vol, source = as_volume(volume, spacing)
    tf = _transfer_function(transfer_function, vol)
    cam = (Camera.from_dict(camera, "camera").with_resolution(width, height) if camera is not None
           else framing_camera(vol, width, height))
    scene = Scene(vol, tf, _lights(lights), cam, g, vol.name, source)
    inputs: dict[str, Any] = {}
    if settings is not None and renderer.input == "transfer":
        from photon_fields.field_cache import cached_transfer
        from photon_fields.runtime.pvrt.transfer import load_transfer

        with numba_threads(threads, "threads"):
            inputs = {"transfer": load_transfer(cached_transfer(scene, settings, seed, root), scene)}
    elif settings is not None:
        from photon_fields.field_cache import cached_input

        path = cached_input(scene, trained, settings, seed, root)
        inputs = _load_input(renderer.input, path, scene, threads)
    with numba_threads(threads, "threads"):
        result = renderer.render_function()(scene, spp=spp, seed=seed, progress=progress, **inputs,
                                            **{known[k].keyword: v for k, v in options.items()})
    info = {"method": method, "spp": spp, "seed": seed, "g": scene.g, "size": [width, height],
            "options": options, "scene_fingerprint": scene.fingerprint(), "transfer_function": tf.to_dict(),
            "lights": [lt.to_dict() for lt in scene.lights], "camera": cam.to_dict(),
            "timings_ms": result.timings_ms, "stats": dict(result.stats)}
    return Image({k: result.layers[k] for k in result.layers}, info)


def _option_name(option: Any) -> str:
    """A renderer option's keyword here: the render function's, unless :func:`render` has a parameter of that name
    (the camera estimator's ``camera``): then the command-line flag's (``camera_estimator``)."""
    return option.flag.lstrip("-").replace("-", "_") if option.keyword in _OWN_PARAMETERS else option.keyword


#: :func:`render`'s own keyword parameters, which a renderer option cannot take as its name.
_OWN_PARAMETERS = tuple(inspect.signature(render).parameters)


def _option(option: Any, keyword: str, value: Any) -> Any:
    """A renderer option checked as the command line checks it (a switch's keyword takes a bool as it is)."""
    from photon_fields.runtime.renderers.registry import negate

    if option.check is negate or option.type is None:
        if not isinstance(value, bool):
            raise InputError(keyword, f"must be True or False, got {value!r}")
        return value
    return option.check(keyword, value) if option.check is not None else value


def _size(size: Any) -> tuple[int, int]:
    try:
        w, h = size
    except (TypeError, ValueError):
        raise InputError("size", f"must be (width, height), got {size!r}") from None
    for v in (w, h):
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 16384:
            raise InputError("size", f"width and height must be integers in [1, 16384], got {size!r}")
    return w, h


def _transfer_function(tf: Any, volume: Any) -> Any:
    from photon_fields.runtime.scene.labels import LabelTransfer
    from photon_fields.runtime.scene.transfer import AUTO, LABELS, PRESETS, TransferFunction

    if isinstance(tf, LabelTransfer):
        tf.check(volume, "transfer_function")
        return tf
    if isinstance(tf, TransferFunction):
        return tf
    if isinstance(tf, dict):
        return TransferFunction.from_dict(tf, "transfer_function", volume=volume)
    if isinstance(tf, (str, os.PathLike)):
        if str(tf) in (AUTO, LABELS) or str(tf) in PRESETS:
            return TransferFunction.from_dict({"preset": str(tf)}, "transfer_function", volume=volume)
        if str(tf).endswith(".json") or Path(tf).exists():
            return TransferFunction.load(Path(tf).expanduser(), volume=volume)
        raise InputError("transfer_function", f"unknown preset {str(tf)!r} and not a .json file (presets: "
                                              f"{AUTO}, {LABELS}, {', '.join(PRESETS)})")
    raise InputError("transfer_function", f"expected a preset name, a .json file, a dict or a TransferFunction, "
                                          f"got {type(tf).__name__}")


def _lights(lights: Any) -> tuple[Any, ...]:
    from photon_fields.runtime.scene.lights import light_from_dict
    from photon_fields.runtime.scene.rigs import light_rig

    if isinstance(lights, str):
        return light_rig(lights)
    if isinstance(lights, (list, tuple)) and lights:
        return tuple(x if not isinstance(x, dict) else light_from_dict(x, f"lights[{i}]")
                     for i, x in enumerate(lights))
    raise InputError("lights", f"expected a rig name or a non-empty list of lights, got {lights!r}")


def _load_input(kind: str, path: Path, scene: Any, threads: int | None) -> dict[str, Any]:
    if kind == "bundle":
        from photon_fields.runtime.field.field import PhotonField

        field = PhotonField.load(path, threads=threads, expected_fingerprint=scene.fingerprint(),
                                 expected_parts=scene.fingerprint_parts(), expected_lights=scene.light_identities())
        return {"estimator": field.estimator()}
    from photon_fields.runtime.photons.estimate import map_for_scene
    from photon_fields.runtime.photons.photon_map import PhotonMap

    pmap, _, _ = map_for_scene(PhotonMap.load(path), scene, False)  # a map of these lights rescaled, or refused
    return {"pmap": pmap, "force": False}
