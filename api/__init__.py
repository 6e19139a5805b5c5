"""photon_fields: render a scientific volume with global illumination in a few lines::

    import photon_fields as pf
    img = pf.render(volume, transfer_function="auto", lights="studio", method="field", spp=16)
    img.save("volume.exr")                    # EXR (layers L, L_d, L_i, L_e) and volume.png beside it

:func:`render` and :class:`Image` are imported on first use (module ``__getattr__``), so ``import photon_fields``
stays cheap: it loads neither numba nor onnxruntime until something is rendered. The subpackages ``runtime``,
``train`` and ``models_spec`` are the product itself; this package is the short way in, and like the runtime it
never imports torch (a field is trained in another process, see :mod:`photon_fields.field_cache`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from photon_fields.image import Image
    from photon_fields.rendering import render
    from photon_fields.runtime.errors import InputError

#: name -> module that defines it.
_LAZY = {"render": "photon_fields.rendering", "Image": "photon_fields.image",
         "InputError": "photon_fields.runtime.errors"}

__all__ = ["Image", "InputError", "render"]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'photon_fields' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])
