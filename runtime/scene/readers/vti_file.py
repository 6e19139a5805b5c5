"""VTK XML ImageData (``.vti``, what ParaView and VTK's ``vtkXMLImageDataWriter`` write), read without VTK.

Only Python's ``xml.etree``, ``base64`` and ``zlib`` are used. The subset read:

- ``<VTKFile type="ImageData">`` with ``byte_order`` ``LittleEndian`` (the default when absent) or
  ``BigEndian``, ``header_type`` ``UInt32`` (the default, as in version 0.1 files) or ``UInt64``, and no
  ``compressor`` or ``compressor="vtkZLibDataCompressor"``. Other dataset types (RectilinearGrid,
  StructuredGrid, UnstructuredGrid, ...) and other compressors (LZ4, LZMA) are refused in one line.
- One ``<Piece>``; its ``Extent`` (else ``WholeExtent``) gives the grid size. ``Spacing`` and ``Origin`` are
  read (default ``1 1 1`` / ``0 0 0``); ``Direction`` is ignored, as the other readers ignore direction cosines.
- One scalar ``<DataArray>`` (``NumberOfComponents`` 1) of type Int8 ... UInt64, Float32 or Float64, from
  ``<PointData>`` (one voxel per point) or ``<CellData>`` (one voxel per cell). Chosen by name with the
  ``array`` option; by default the ``Scalars`` array of PointData, else its first array, else the same in
  CellData. Multi-component arrays (vectors, RGB) are refused: which scalar to derive (a component, the
  magnitude) is a modelling choice left to the user (ParaView's Calculator writes it as a scalar array).
- Every encoding VTK writes: ``format="ascii"``; ``format="binary"`` (inline base64); ``format="appended"``
  with ``<AppendedData encoding="raw">`` or ``encoding="base64"``. Binary data start with a header of
  ``header_type`` integers: the byte count for uncompressed data (base64-encoded together with the data),
  or ``[nb, bs, lbs, cs_0 .. cs_nb-1]`` for zlib blocks (the header base64-encoded on its own, then the
  blocks as one stream): ``nb`` blocks of ``bs`` bytes before compression, the last one ``lbs`` bytes
  (``bs`` when ``lbs`` is 0), block ``i`` ``cs_i`` bytes compressed.

Orientation: VTK stores points x fastest, then y, then z, so the ``[x, y, z]`` array is the Fortran-order
reshape of the values. Memory: appended raw uncompressed data are memory-mapped (only the XML head is read
into memory); compressed blocks are inflated one at a time into the output buffer.
"""

from __future__ import annotations

import base64
import binascii
import math
import mmap
import xml.etree.ElementTree as ET
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from photon_fields.runtime.errors import InputError
from photon_fields.runtime.scene.readers.params import ReadResult, Spacing, fmt, spacing_or_none

_VTK_TYPES = {"Int8": "i1", "UInt8": "u1", "Int16": "i2", "UInt16": "u2", "Int32": "i4", "UInt32": "u4",
              "Int64": "i8", "UInt64": "u8", "Float32": "f4", "Float64": "f8"}
_HEADER_TYPES = {"UInt32": 4, "UInt64": 8}
_BYTE_ORDERS = {"LittleEndian": "<", "BigEndian": ">"}
ZLIB_COMPRESSOR = "vtkZLibDataCompressor"
_APPENDED = b"<AppendedData"


@dataclass(frozen=True)
class VtiImage:
    """What a ``.vti`` file holds of interest here: the chosen array indexed ``[x, y, z]`` and the geometry."""

    data: np.ndarray
    spacing: Spacing
    origin: tuple[float, float, float]
    array: str
    association: str  # "PointData" or "CellData"


def read_vti(path: Path, what: str, array: str | None, spacing_given: bool) -> ReadResult:
    """The reader interface of :mod:`photon_fields.runtime.scene.volume_io` (the origin is not used: volumes
    sit in a centred box)."""
    image = read_vti_image(path, what, array, spacing_given)
    return image.data, image.spacing, None


def read_vti_image(path: Path, what: str, array: str | None = None, spacing_given: bool = False) -> VtiImage:
    """Read the scalar array ``array`` (default: see the module docstring) of the ImageData file ``path``."""
    with open(path, "rb") as f:
        if path.stat().st_size == 0:
            raise InputError(what, "empty file (not a VTK XML ImageData file)")
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            head, appended = _split_appended(mm, what)
            root = _parse_xml(head, what)
            return _read_image(path, root, mm, appended, what, array, spacing_given)


# ----------------------------------------------------------------------------------------------------------
# XML structure


def _split_appended(mm: mmap.mmap, what: str) -> tuple[bytes, tuple[int, str] | None]:
    """The XML text (with an appended section cut off: raw binary is not XML) and, if the file has an
    ``<AppendedData>`` section, the file offset of its data (after the ``_`` marker) and its encoding."""
    start = mm.find(_APPENDED)
    if start < 0:
        return mm[:], None
    end = mm.find(b">", start)
    if end < 0:
        raise InputError(what, "truncated: the <AppendedData> tag is not closed")
    tag = mm[start:end + 1]
    try:
        attrib = ET.fromstring(tag if tag.endswith(b"/>") else tag[:-1] + b"/>").attrib
    except ET.ParseError as err:
        raise InputError(what, f"not valid VTK XML: bad <AppendedData> tag ({err})") from None
    underscore = mm.find(b"_", end)
    if underscore < 0 or mm[end + 1:underscore].strip():
        raise InputError(what, "corrupt <AppendedData>: its data must start with '_'")
    encoding = attrib.get("encoding", "base64")
    if encoding not in ("raw", "base64"):
        raise InputError(what, f"<AppendedData> encoding {encoding!r} is not read; expected 'raw' or 'base64'")
    return mm[:start] + b"</VTKFile>", (underscore + 1, encoding)


def _parse_xml(head: bytes, what: str) -> ET.Element:
    try:
        root = ET.fromstring(head)
    except ET.ParseError as err:
        raise InputError(what, f"not valid VTK XML ({err})") from None
    if root.tag != "VTKFile":
        raise InputError(what, f"not a VTK XML file (root element <{root.tag}>, expected <VTKFile>)")
    return root


def _ints(text: str | None, n: int, what: str, label: str) -> list[int]:
    try:
        values = [int(v) for v in (text or "").split()]
    except ValueError:
        values = []
    if len(values) != n:
        raise InputError(what, f"{label} must be {n} integers, got {fmt(text)}")
    return values


def _floats(text: str | None, default: str, what: str, label: str) -> tuple[float, float, float]:
    try:
        values = [float(v) for v in (text if text is not None else default).split()]
    except ValueError:
        values = []
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise InputError(what, f"{label} must be 3 finite numbers, got {fmt(text)}")
    return values[0], values[1], values[2]


def _read_image(path: Path, root: ET.Element, mm: mmap.mmap, appended: tuple[int, str] | None, what: str,
                array: str | None, spacing_given: bool) -> VtiImage:
    kind = root.get("type")
    if kind != "ImageData":
        raise InputError(what, f"VTK dataset type {kind!r} is not read; only ImageData (.vti) volumes are "
                         "(resample to an image first, e.g. ParaView's Resample To Image, and save as .vti)")
    order = _BYTE_ORDERS.get(root.get("byte_order", "LittleEndian"))
    if order is None:
        raise InputError(what, f"byte_order {root.get('byte_order')!r} is not LittleEndian or BigEndian")
    header_size = _HEADER_TYPES.get(root.get("header_type", "UInt32"))
    if header_size is None:
        raise InputError(what, f"header_type {root.get('header_type')!r} is not UInt32 or UInt64")
    compressor = root.get("compressor")
    if compressor not in (None, "", ZLIB_COMPRESSOR):
        raise InputError(what, f"compressor {compressor!r} is not read; only {ZLIB_COMPRESSOR} (zlib) or none "
                         "(re-save from ParaView with zlib or no compression)")
    image = root.find("ImageData")
    if image is None:
        raise InputError(what, "no <ImageData> element")
    pieces = image.findall("Piece")
    if len(pieces) != 1:
        raise InputError(what, f"has {len(pieces)} <Piece> elements; only single-piece .vti files are read "
                         "(merge the pieces, e.g. save the whole image from ParaView)")
    piece = pieces[0]
    extent_text = piece.get("Extent", image.get("WholeExtent"))
    ext = _ints(extent_text, 6, what, "Extent")
    points = tuple(ext[2 * i + 1] - ext[2 * i] + 1 for i in range(3))
    if min(points) < 1:
        raise InputError(what, f"Extent {fmt(extent_text)} is empty (an upper bound below its lower bound)")
    spacing_text = image.get("Spacing")
    raw_spacing = _floats(spacing_text, "1 1 1", what, "Spacing")
    spacing = spacing_or_none(np.abs(raw_spacing))
    if spacing is None and not spacing_given:
        raise InputError(what, f"Spacing {fmt(spacing_text)} has a zero entry; pass spacing=(sx, sy, sz)")
    origin = _floats(image.get("Origin"), "0 0 0", what, "Origin")

    association, element = _choose_array(piece, what, array)
    name = element.get("Name", "(unnamed)")
    dims = points if association == "PointData" else tuple(n - 1 for n in points)
    if min(dims) < 1:
        raise InputError(what, f"CellData array {name!r} has no cells: Extent {fmt(extent_text)} is flat")
    vtk_type = element.get("type")
    if vtk_type not in _VTK_TYPES:
        raise InputError(what, f"array {name!r} has type {vtk_type!r}; expected a numeric type "
                         f"({', '.join(_VTK_TYPES)})")
    components = element.get("NumberOfComponents", "1")
    if components != "1":
        raise InputError(what, f"array {name!r} has {components} components; only scalar arrays are read "
                         "(pick a scalar array with \"array\", or derive one, e.g. a component or the "
                         "magnitude, with ParaView's Calculator)")
    dtype = np.dtype(_VTK_TYPES[vtk_type]).newbyteorder(order)
    count = dims[0] * dims[1] * dims[2]
    codec = _Codec(path, what, name, order, dtype, count, header_size, compressor == ZLIB_COMPRESSOR, dims)
    flat = _decode(element, codec, mm, appended)
    data = flat.reshape(dims, order="F")  # x fastest: Fortran order of [x, y, z]
    return VtiImage(data, spacing or (1.0, 1.0, 1.0), origin, name, association)


def _choose_array(piece: ET.Element, what: str, array: str | None) -> tuple[str, ET.Element]:
    groups = [(assoc, piece.find(assoc)) for assoc in ("PointData", "CellData")]
    found = [(assoc, g, g.findall("DataArray")) for assoc, g in groups if g is not None]
    if array is not None:
        for assoc, _group, arrays in found:
            for element in arrays:
                if element.get("Name") == array:
                    return assoc, element
        names = [str(e.get("Name")) for _a, _g, arrays in found for e in arrays]
        raise InputError(what, f"no data array named {array!r}; the file has {', '.join(map(repr, names)) or 'none'}")
    for assoc, group, arrays in found:
        scalars = group.get("Scalars")
        for element in arrays:
            if scalars is None or element.get("Name") == scalars:
                return assoc, element
    raise InputError(what, "no PointData or CellData array to read")


# ----------------------------------------------------------------------------------------------------------
# Data decoding


@dataclass(frozen=True)
class _Codec:
    """How one array's bytes are to be read, and its errors phrased."""

    path: Path
    what: str
    name: str
    order: str  # "<" or ">"
    dtype: np.dtype
    count: int
    header_size: int
    zlib: bool
    dims: tuple[int, ...]

    def fail(self, problem: str) -> InputError:
        return InputError(self.what, f"array {self.name!r}: {problem}")

    def check_size(self, nbytes: int) -> None:
        """The data hold exactly the extent's values (fewer: truncated; more: a wrong extent or type)."""
        need = self.count * self.dtype.itemsize
        if nbytes != need:
            short = "data shorter than the extent" if nbytes < need else "data longer than the extent"
            nx, ny, nz = self.dims
            raise self.fail(f"{short}: {nbytes} bytes, but {nx}x{ny}x{nz} {self.dtype.name} values need {need}")

    def header(self, raw: bytes) -> list[int]:
        """The header integers (``header_type``, in the file's byte order) in ``raw``."""
        dt = np.dtype(f"u{self.header_size}").newbyteorder(self.order)
        return [int(v) for v in np.frombuffer(raw, dtype=dt)]


class _Source:
    """Random access to the encoded bytes of binary data (inline base64 text, or the appended section):
    ``stream(pos, n)`` decodes the first ``n`` bytes of the stream that starts at ``pos``."""

    def __init__(self, buf: bytes | mmap.mmap, b64: bool, codec: _Codec) -> None:
        self.buf, self.b64, self.codec = buf, b64, codec

    def encoded_length(self, n: int) -> int:
        return 4 * math.ceil(n / 3) if self.b64 else n

    def stream(self, pos: int, n: int) -> bytes:
        chunk = self.buf[pos:pos + self.encoded_length(n)]
        if self.b64:
            try:
                chunk = base64.b64decode(chunk, validate=True)
            except (binascii.Error, ValueError) as err:
                raise self.codec.fail(f"bad base64 data ({err})") from None
        if len(chunk) < n:
            raise self.codec.fail(f"truncated: {n} bytes expected, {len(chunk)} in the file")
        return chunk[:n]


def _decode(element: ET.Element, codec: _Codec, mm: mmap.mmap, appended: tuple[int, str] | None) -> np.ndarray:
    fmt_ = element.get("format")
    if fmt_ == "ascii":
        try:
            values = np.array((element.text or "").split(), dtype=codec.dtype.newbyteorder("="))
        except (ValueError, OverflowError) as err:
            raise codec.fail(f"bad ascii value ({err})") from None
        codec.check_size(values.size * codec.dtype.itemsize)
        return values
    if fmt_ == "binary":
        text = b"".join((element.text or "").encode("ascii", "replace").split())
        return _decode_binary(_Source(text, True, codec), 0, codec, None)
    if fmt_ == "appended":
        if appended is None:
            raise codec.fail("format is 'appended' but the file has no <AppendedData> section")
        try:
            offset = int(element.get("offset", ""))
        except ValueError:
            raise codec.fail(f"bad appended offset {element.get('offset')!r}") from None
        start, encoding = appended
        if offset < 0 or start + offset > len(mm):
            raise codec.fail(f"truncated: appended offset {offset} is past the end of the file")
        memmap_at = start + offset if encoding == "raw" else None
        return _decode_binary(_Source(mm, encoding == "base64", codec), start + offset, codec, memmap_at)
    raise codec.fail(f"format {fmt_!r} is not 'ascii', 'binary' or 'appended'")


def _decode_binary(src: _Source, pos: int, codec: _Codec, memmap_at: int | None) -> np.ndarray:
    hs = codec.header_size
    if not codec.zlib:
        nbytes = codec.header(src.stream(pos, hs))[0]
        codec.check_size(nbytes)
        if memmap_at is not None:  # appended raw: map the file instead of reading it
            if memmap_at + hs + nbytes > len(src.buf):
                raise codec.fail(f"truncated: {nbytes} bytes expected, {len(src.buf) - memmap_at - hs} in the file")
            return np.memmap(codec.path, dtype=codec.dtype, mode="r", offset=memmap_at + hs, shape=(codec.count,))
        return np.frombuffer(src.stream(pos, hs + nbytes)[hs:], dtype=codec.dtype)
    nb = codec.header(src.stream(pos, 3 * hs))[0]
    if nb > 1 + codec.count * codec.dtype.itemsize:  # more blocks than bytes: a corrupt header
        raise codec.fail(f"corrupt compression header ({nb} blocks)")
    header = codec.header(src.stream(pos, (3 + nb) * hs))
    bs, lbs, sizes = header[1], header[2], header[3:]
    total = 0 if nb == 0 else (nb - 1) * bs + (lbs if lbs else bs)
    codec.check_size(total)
    blocks_at = pos + src.encoded_length((3 + nb) * hs)
    compressed = src.stream(blocks_at, sum(sizes)) if src.b64 else None
    out = bytearray(total)
    done = read = 0
    for i, size in enumerate(sizes):
        block = compressed[read:read + size] if compressed is not None else src.stream(blocks_at + read, size)
        expected = lbs if (i == nb - 1 and lbs) else bs
        try:
            inflated = zlib.decompress(block)
        except zlib.error as err:
            raise codec.fail(f"zlib error in block {i} of {nb} ({err})") from None
        if len(inflated) != expected:
            raise codec.fail(f"zlib block {i} inflates to {len(inflated)} bytes, the header says {expected}")
        out[done:done + expected] = inflated
        done += expected
        read += size
    return np.frombuffer(out, dtype=codec.dtype)
