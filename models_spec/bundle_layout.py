"""The bundle's fixed names and numbers (format, versions, file and array names, ONNX tensor names and opset) and
:class:`BundleError`, the one-line refusal of a bundle or manifest: the base the schema
(:mod:`photon_fields.models_spec.bundle_schema`) and the manifest (:mod:`photon_fields.models_spec.bundle_manifest`)
build on. The format itself is documented in :mod:`photon_fields.models_spec.bundle`, which re-exports all of it.
"""

from __future__ import annotations

BUNDLE_FORMAT = "photon-fields/field-bundle"
BUNDLE_VERSION = 2
#: Manifest versions this build reads (older ones against :func:`manifest_schema` of their version).
READABLE_VERSIONS = (1, 2)
BUNDLE_SUFFIX = ".pfn"
MANIFEST_FILE = "manifest.json"
ONNX_FILE = "field.onnx"
TABLES_FILE = "tables.npz"
BUNDLE_FILES = (MANIFEST_FILE, ONNX_FILE, TABLES_FILE)
#: The arrays of ``tables.npz``, in input-column order.
TABLE_ARRAYS = ("position", "direction")
TABLE_DTYPES = ("float32", "float16")
#: The ``tables.npz`` array of the surface input's grid, in a bundle whose field has it
#: (:mod:`photon_fields.models_spec.surface`), and its dtype (whatever the hash tables').
SURFACE_ARRAY = "surface"
SURFACE_DTYPE = "int8"
ONNX_INPUT = "features"
ONNX_OUTPUT = "encoded_radiance"
BATCH_AXIS = "batch"
#: Opset 17 / IR 8: old enough for every onnxruntime this project accepts (>= 1.17), and the graph only
#: needs MatMul and Relu.
ONNX_OPSET = 17
ONNX_IR_VERSION = 8
OUTPUT_ENCODING = "eq6-log10"
#: A manifest is a few KB; anything far larger is not one (and is not read into memory).
MAX_MANIFEST_BYTES = 1 << 20


class BundleError(ValueError):
    """A bundle (or a manifest) is not acceptable. ``str(err)`` is one line: ``'<what>: <problem>'``; the
    runtime re-raises it as ``photon_fields.runtime.errors.InputError`` with the same text."""

    def __init__(self, what: str, problem: str) -> None:
        self.what = str(what)
        self.problem = " ".join(str(problem).split())
        super().__init__(f"{self.what}: {self.problem}")
