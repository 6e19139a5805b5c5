"""An ``.npz`` whose metadata is one JSON object stored as a uint8 array beside the data arrays: the layout the
photon map (:mod:`photon_fields.models_spec.photon_map`, entry ``meta``) and the PVRT transfer
(:mod:`photon_fields.models_spec.pvrt_transfer`, entry ``manifest``) share.

:class:`NpzManifestFormat` describes one such format (its name and version, the JSON's keys, the arrays beside it,
what messages call it) and reads it: :meth:`NpzManifestFormat.read` loads every array (``allow_pickle=False``),
:meth:`NpzManifestFormat.read_headers` only the arrays' ``.npy`` headers (shape and dtype, no data). Both make the
checks every such file needs, once for both formats: a readable zip, the JSON entry, its format name and version,
its keys (none unknown, every required one present) and the array names (exactly the format's). The arrays'
dtypes, shapes and values and the JSON's values are each format's own business (``runtime/photons/photon_map.py``,
``runtime/pvrt/transfer.py``). Every refusal is a one-line :class:`NpzError` naming the file; the runtime
re-raises it as its ``InputError`` with the same text.

numpy and the standard library only (the runtime imports this with torch absent).
"""

from __future__ import annotations

import json
import zipfile
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from photon_fields.models_spec.json_keys import keys_problem

#: Array name -> (shape, dtype), from the ``.npy`` headers alone (:meth:`NpzManifestFormat.read_headers`).
ArrayHeaders = dict[str, tuple[tuple[int, ...], np.dtype]]

# What np.load / zipfile raise for a file that is not a readable .npz (truncated, not a zip, a bad .npy header).
_UNREADABLE = (OSError, ValueError, zipfile.BadZipFile, EOFError)


class NpzError(ValueError):
    """A file of an npz-manifest format is not acceptable. ``str(err)`` is one line: ``'<what>: <problem>'``."""

    def __init__(self, what: str, problem: str) -> None:
        self.what = str(what)
        self.problem = " ".join(str(problem).split())
        super().__init__(f"{self.what}: {self.problem}")


@dataclass(frozen=True)
class NpzManifestFormat:
    """One npz-with-a-JSON-manifest format, and its reader (module docstring)."""

    #: What messages call a file of the format: ``"photon map"``, ``"PVRT transfer"``.
    kind: str
    #: The JSON's ``format`` value, and the one ``version`` this build reads.
    format: str
    version: int
    #: The array that holds the JSON (UTF-8 bytes as uint8), and what messages call the JSON.
    entry: str
    label: str
    #: The JSON's allowed keys and the ones it must have.
    keys: tuple[str, ...]
    required: tuple[str, ...]
    #: The data arrays beside the entry: a file holds these, and of :attr:`optional` those it has, nothing else.
    arrays: tuple[str, ...]
    #: What to do with a file of another version: ``"re-trace it"``.
    remedy: str
    #: Data arrays a file may hold besides :attr:`arrays` (added to a format without a version change).
    optional: tuple[str, ...] = ()

    def read(self, path: str | Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """The checked JSON and the data arrays (the entry left out) of the file at ``path``."""
        what = str(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except _UNREADABLE as exc:
            raise NpzError(what, f"not a readable {self.kind} (.npz): {exc}") from None
        if self.entry not in arrays:
            raise self._no_entry(what)
        manifest = self.parse_manifest(arrays.pop(self.entry), what)
        self.check_array_names(arrays, what)
        return manifest, arrays

    def read_headers(self, path: str | Path) -> tuple[dict[str, Any], ArrayHeaders]:
        """The checked JSON and each data array's (shape, dtype), read from the ``.npy`` headers only: no data
        array is read (a map's 5M photons are ~185 MB)."""
        what = str(path)
        headers: ArrayHeaders = {}
        try:
            with zipfile.ZipFile(path) as z:
                names = {n[:-4] if n.endswith(".npy") else n: n for n in z.namelist()}
                if self.entry not in names:
                    raise self._no_entry(what)
                with z.open(names[self.entry]) as f:
                    raw = np.lib.format.read_array(f, allow_pickle=False)
                for name in names.keys() - {self.entry}:
                    with z.open(names[name]) as f:
                        headers[name] = _npy_header(f)
        except NpzError:
            raise
        except _UNREADABLE as exc:
            raise NpzError(what, f"not a readable {self.kind} (.npz): {exc}") from None
        manifest = self.parse_manifest(raw, what)
        self.check_array_names(headers, what)
        return manifest, headers

    def parse_manifest(self, raw: np.ndarray, what: str) -> dict[str, Any]:
        """The entry's JSON, checked for format, version and keys (its values are the format's business)."""
        try:
            meta = json.loads(np.asarray(raw).tobytes().decode())
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise NpzError(what, f"corrupt {self.kind} {self.label} ({exc})") from None
        if not isinstance(meta, dict) or meta.get("format") != self.format:
            found = meta.get("format") if isinstance(meta, dict) else None
            raise NpzError(what, f"not a {self.kind} (format {found!r}, expected {self.format!r})")
        if meta.get("version") != self.version:
            raise NpzError(what, f"{self.kind} version {meta.get('version')!r} is not supported (this build reads "
                           f"version {self.version}); {self.remedy}")
        problem = keys_problem(meta, self.keys, self.required)
        if problem is not None:
            raise NpzError(f"{what} {self.label}", problem)
        return meta

    def check_array_names(self, names: Collection[str], what: str) -> None:
        """Refuse data arrays other than :attr:`arrays` and :attr:`optional` (named), then a missing one."""
        extra = sorted(set(names) - set(self.arrays) - set(self.optional))
        if extra:
            raise NpzError(what, f"unknown array{'s' if len(extra) > 1 else ''} {', '.join(map(repr, extra))}; a "
                           f"{self.kind} holds {', '.join(map(repr, [*self.arrays, self.entry, *self.optional]))}")
        for name in self.arrays:
            if name not in names:
                raise NpzError(what, f"{self.kind} lacks the '{name}' array")

    def _no_entry(self, what: str) -> NpzError:
        return NpzError(what, f"not a {self.kind}: no '{self.entry}' entry")


def _npy_header(f: IO[bytes]) -> tuple[tuple[int, ...], np.dtype]:
    """(shape, dtype) from an ``.npy`` stream's header, the stream left at the data."""
    version = np.lib.format.read_magic(f)
    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, _, dtype = read(f)
    return tuple(shape), np.dtype(dtype)
