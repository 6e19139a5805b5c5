"""Tests for the VTK XML ImageData reader (runtime/scene/readers/vti_file.py) through load_volume.

Test files come from a small writer written here from the format description (struct, base64, zlib), not
from the reader's code: every encoding (ascii, inline base64, appended raw, appended base64), zlib blocks,
both byte orders and both header types. If VTK or PyVista happens to be installed, files written by it are
read too (skipped otherwise; neither is installed for the tests).
"""

from __future__ import annotations

import base64
import json
import struct
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from volume_helpers import expected_norm, one_line_error

import photon_fields.runtime.scene.volume_io as vio
from photon_fields.runtime.scene.readers.vti_file import read_vti_image
from photon_fields.runtime.scene.volume import Volume
from photon_fields.runtime.scene.volume_io import load_volume

NX, NY, NZ = 5, 7, 9  # distinct sizes per axis: a swapped axis changes the shape
VTK_TYPES = {"i1": "Int8", "u1": "UInt8", "i2": "Int16", "u2": "UInt16", "i4": "Int32", "u4": "UInt32",
             "i8": "Int64", "u8": "UInt64", "f4": "Float32", "f8": "Float64"}


def pattern(dtype: Any = np.float32, shape: tuple[int, int, int] = (NX, NY, NZ)) -> np.ndarray:
    """Indexed [x, y, z]: value = x + 10 y + 100 z (0 .. 864 for 5x7x9)."""
    x, y, z = np.meshgrid(*(np.arange(n) for n in shape), indexing="ij")
    return (x + 10 * y + 100 * z).astype(dtype)


# ----------------------------------------------------------------------------------------------------------
# An independent .vti writer


def _encode(payload: bytes, order: str, header_type: str, compress: bool, b64: bool, block: int) -> bytes:
    """One array's binary data as VTK writes it: header + data (uncompressed, one base64 stream), or the
    block header [nb, bs, lbs, cs...] and the zlib blocks (base64: header and blocks encoded separately)."""
    h = order + ("I" if header_type == "UInt32" else "Q")
    if not compress:
        stream = struct.pack(h, len(payload)) + payload
        return base64.b64encode(stream) if b64 else stream
    blocks = [payload[i:i + block] for i in range(0, len(payload), block)]
    packed = [zlib.compress(b) for b in blocks]
    last = len(payload) % block
    header = struct.pack(order + ("I" if header_type == "UInt32" else "Q") * (3 + len(blocks)),
                         len(blocks), block, last, *(len(p) for p in packed))
    if b64:
        return base64.b64encode(header) + base64.b64encode(b"".join(packed))
    return header + b"".join(packed)


def write_vti(path: Path, arrays: dict[str, np.ndarray] | np.ndarray, *, fmt: str = "appended", encoding: str = "raw",
              compress: bool = False, byte_order: str = "LittleEndian", header_type: str = "UInt32",
              spacing: tuple[float, ...] = (1.0, 1.0, 1.0), origin: tuple[float, ...] = (0.0, 0.0, 0.0),
              cell: bool = False, scalars: str | None = "", block: int = 100, start: tuple[int, ...] = (2, 0, -3),
              components: int = 1, dataset: str = "ImageData") -> Path:
    """Write ``arrays`` (name -> [x, y, z] array; a bare array is named "density") as a .vti file.
    ``scalars=""`` marks the first array as Scalars, None marks none. Point dims = array dims (+1 if cell)."""
    if isinstance(arrays, np.ndarray):
        arrays = {"density": arrays}
    order = "<" if byte_order == "LittleEndian" else ">"
    shape = next(iter(arrays.values())).shape[:3]
    points = [n + 1 for n in shape] if cell else list(shape)
    extent = " ".join(f"{s} {s + n - 1}" for s, n in zip(start, points, strict=True))
    compressor = ' compressor="vtkZLibDataCompressor"' if compress else ""
    appended = b""
    elements = []
    for name, arr in arrays.items():
        dt = arr.dtype.newbyteorder(order)
        if components > 1:  # arr is [x, y, z, c]: tuples x fastest, components interleaved
            flat = np.stack([arr[..., c].ravel(order="F") for c in range(components)], axis=1)
        else:
            flat = arr.ravel(order="F")
        payload = np.ascontiguousarray(flat, dtype=dt).tobytes()
        attrs = f'type="{VTK_TYPES[arr.dtype.str[1:]]}" Name="{name}" NumberOfComponents="{components}"'
        if fmt == "ascii":
            text = " ".join(repr(v) for v in np.asarray(flat).ravel().tolist())
            elements.append(f'<DataArray {attrs} format="ascii">\n{text}\n</DataArray>')
        elif fmt == "binary":
            text = _encode(payload, order, header_type, compress, True, block).decode()
            elements.append(f'<DataArray {attrs} format="binary">\n  {text}\n</DataArray>')
        else:
            elements.append(f'<DataArray {attrs} format="appended" offset="{len(appended)}"/>')
            appended += _encode(payload, order, header_type, compress, encoding == "base64", block)
    first = next(iter(arrays))
    scal = "" if scalars is None else f' Scalars="{scalars or first}"'
    group = "CellData" if cell else "PointData"
    other = "PointData" if cell else "CellData"
    xml = (f'<?xml version="1.0"?>\n<VTKFile type="{dataset}" version="1.0" byte_order="{byte_order}" '
           f'header_type="{header_type}"{compressor}>\n'
           f'  <{dataset} WholeExtent="{extent}" Origin="{" ".join(map(repr, origin))}" '
           f'Spacing="{" ".join(map(repr, spacing))}" Direction="1 0 0 0 1 0 0 0 1">\n'
           f'  <Piece Extent="{extent}">\n    <{group}{scal}>\n      ' + "\n      ".join(elements) +
           f"\n    </{group}>\n    <{other}>\n    </{other}>\n  </Piece>\n  </{dataset}>\n")
    body = xml.encode()
    if fmt == "appended":
        body += f'  <AppendedData encoding="{encoding}">\n   _'.encode() + appended + b"\n  </AppendedData>\n"
    path.write_bytes(body + b"</VTKFile>\n")
    return path


def appended_start(raw: bytes | bytearray) -> int:
    """Offset of the appended data: after the ``_`` that follows the <AppendedData> tag."""
    return raw.index(b"_", raw.index(b"<AppendedData")) + 1


# ----------------------------------------------------------------------------------------------------------
# Round trips: every encoding

BINARY_VARIANTS = [(fmt, enc, comp, bo, ht) for fmt, enc in (("binary", "base64"), ("appended", "raw"),
                                                           ("appended", "base64"))
                   for comp in (False, True) for bo in ("LittleEndian", "BigEndian") for ht in ("UInt32", "UInt64")]


@pytest.mark.parametrize(("fmt", "encoding", "compress", "byte_order", "header_type"),
                         [("ascii", "raw", False, "LittleEndian", "UInt32"), *BINARY_VARIANTS])
def test_roundtrip_every_encoding(tmp_path: Path, fmt: str, encoding: str, compress: bool, byte_order: str,
                                  header_type: str) -> None:
    data = pattern(np.uint16) * 50  # up to 43200: both bytes matter, so a byte-order mix-up shows
    path = write_vti(tmp_path / "v.vti", data, fmt=fmt, encoding=encoding, compress=compress,
                     byte_order=byte_order, header_type=header_type, spacing=(0.5, 1.0, 2.5), origin=(1, -2, 3.5))
    vol = load_volume(path)
    assert isinstance(vol, Volume) and vol.dims == (NX, NY, NZ) and vol.name == "v"
    np.testing.assert_array_equal(vol.data, expected_norm(data))
    assert vol.spacing == pytest.approx((0.5, 1.0, 2.5))
    image = read_vti_image(path, str(path))
    np.testing.assert_array_equal(image.data, data)
    assert image.origin == (1.0, -2.0, 3.5) and image.array == "density" and image.association == "PointData"


@pytest.mark.parametrize("block", [16, 50, NX * NY * NZ * 4])  # partial last block; lbs = 0 (exact); one block
@pytest.mark.parametrize("fmt", ["binary", "appended"])
def test_zlib_block_layouts(tmp_path: Path, block: int, fmt: str) -> None:
    data = pattern(np.float32) / 7
    path = write_vti(tmp_path / "z.vti", data, fmt=fmt, compress=True, block=block)
    np.testing.assert_array_equal(read_vti_image(path, "z").data, data)


def test_orientation_x_fastest(tmp_path: Path) -> None:
    """Voxel [x, y, z] holds x + 10 y + 100 z: the values are x fastest (a Fortran-order reshape)."""
    data = pattern(np.float32)
    path = write_vti(tmp_path / "o.vti", data, fmt="ascii")
    vol = load_volume(path)
    assert vol.dims == (5, 7, 9)
    assert vol.data[4, 0, 0] == pytest.approx(4 / 864)
    assert vol.data[0, 6, 0] == pytest.approx(60 / 864)
    assert vol.data[0, 0, 8] == pytest.approx(800 / 864)
    assert vol.data[1, 2, 3] == pytest.approx(321 / 864)


@pytest.mark.parametrize("dt", list(VTK_TYPES))
def test_every_numeric_type(tmp_path: Path, dt: str) -> None:
    data = pattern(dt) if dt not in ("i1", "u1") else (pattern(np.int32) % 100).astype(dt)
    for fmt in ("ascii", "appended"):
        path = write_vti(tmp_path / f"{dt}_{fmt}.vti", data, fmt=fmt, byte_order="BigEndian")
        image = read_vti_image(path, str(path))
        assert image.data.dtype.kind == np.dtype(dt).kind and image.data.dtype.itemsize == np.dtype(dt).itemsize
        np.testing.assert_array_equal(image.data, data)


def test_cell_data(tmp_path: Path) -> None:
    """CellData: one voxel per cell, so the point extent is one larger per axis."""
    data = pattern(np.float64)
    path = write_vti(tmp_path / "c.vti", data, cell=True, fmt="binary", compress=True)
    image = read_vti_image(path, "c")
    assert image.association == "CellData"
    np.testing.assert_array_equal(image.data, data)
    assert load_volume(path).dims == (NX, NY, NZ)


def test_array_choice(tmp_path: Path) -> None:
    first, second = pattern(np.float32), pattern(np.float32)[::-1].copy()
    arrays = {"first": first, "second": second}
    # Scalars names the second array: it is the default.
    path = write_vti(tmp_path / "a.vti", arrays, scalars="second")
    np.testing.assert_array_equal(load_volume(path).data, expected_norm(second))
    np.testing.assert_array_equal(load_volume(path, array="first").data, expected_norm(first))
    # No Scalars attribute: the first array.
    path = write_vti(tmp_path / "b.vti", arrays, scalars=None, fmt="binary")
    np.testing.assert_array_equal(load_volume(path).data, expected_norm(first))
    np.testing.assert_array_equal(load_volume(path, array="second").data, expected_norm(second))
    msg = one_line_error(path, "no data array named 'third'", array="third")
    assert "'first', 'second'" in msg


def test_array_from_the_scene_entry(tmp_path: Path) -> None:
    from photon_fields.runtime.scene.scene import load_scene

    write_vti(tmp_path / "s.vti", {"first": pattern(), "second": pattern()[::-1].copy()}, spacing=(1, 1, 2))
    scene = {"volume": {"path": "s.vti", "array": "second"}, "transfer_function": {"preset": "grey_ramp"},
             "lights": [{"type": "directional", "direction": [0, -1, 0]}],
             "camera": {"eye": [2, 0, 0], "target": [0, 0, 0]}}
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    loaded = load_scene(tmp_path / "scene.json")
    np.testing.assert_array_equal(loaded.volume.data, expected_norm(pattern()[::-1]))
    assert loaded.volume.spacing == (1.0, 1.0, 2.0)
    assert loaded.volume_source is not None and loaded.volume_source["array"] == "second"


def test_spacing_argument_overrides_file(tmp_path: Path) -> None:
    path = write_vti(tmp_path / "sp.vti", pattern(), spacing=(3, 3, 3))
    assert load_volume(path, spacing=(1, 2, 3)).spacing == (1.0, 2.0, 3.0)


def test_appended_raw_is_memory_mapped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[np.ndarray] = []
    real = vio.make_volume
    monkeypatch.setattr(vio, "make_volume", lambda raw, *a, **k: seen.append(raw) or real(raw, *a, **k))
    load_volume(write_vti(tmp_path / "m.vti", pattern(), fmt="appended", encoding="raw"))
    assert len(seen) == 1 and isinstance(seen[0], np.memmap) and not seen[0].flags.writeable
    load_volume(write_vti(tmp_path / "n.vti", pattern(), fmt="appended", encoding="raw", compress=True))
    assert not isinstance(seen[1], np.memmap)


def test_files_written_by_vtk(tmp_path: Path) -> None:
    """The writer ParaView uses, if installed: vtkXMLImageDataWriter in its default mode (appended,
    zlib-compressed, base64 or raw) and in ascii."""
    vtk = pytest.importorskip("vtk", reason="vtk is not installed (not a test dependency; nothing to compare)")
    from vtk.util.numpy_support import numpy_to_vtk  # type: ignore[import-not-found]

    data = pattern(np.float32)
    image = vtk.vtkImageData()
    image.SetDimensions(NX, NY, NZ)
    image.SetSpacing(0.5, 1.0, 2.0)
    arr = numpy_to_vtk(data.ravel(order="F"), deep=True)
    arr.SetName("density")
    image.GetPointData().SetScalars(arr)
    for mode, encode in (("appended", True), ("appended", False), ("binary", True), ("ascii", True)):
        writer = vtk.vtkXMLImageDataWriter()
        writer.SetInputData(image)
        path = tmp_path / f"vtk_{mode}_{encode}.vti"
        writer.SetFileName(str(path))
        {"appended": writer.SetDataModeToAppended, "binary": writer.SetDataModeToBinary,
         "ascii": writer.SetDataModeToAscii}[mode]()
        writer.SetEncodeAppendedData(encode)
        assert writer.Write() == 1
        vol = load_volume(path)
        np.testing.assert_array_equal(vol.data, expected_norm(data))
        assert vol.spacing == (0.5, 1.0, 2.0)


# ----------------------------------------------------------------------------------------------------------
# Bad input: one line naming the file


def test_bad_xml(tmp_path: Path) -> None:
    path = tmp_path / "x.vti"
    path.write_text('<?xml version="1.0"?>\n<VTKFile type="ImageData"><ImageData WholeExtent="0 1 0 1 0 1">')
    one_line_error(path, "not valid VTK XML")
    path.write_text("")
    one_line_error(path, "empty file")
    path.write_text("<html><body>not vtk</body></html>")
    one_line_error(path, "not a VTK XML file")


def test_bad_base64(tmp_path: Path) -> None:
    path = write_vti(tmp_path / "b.vti", pattern(), fmt="binary")
    text = path.read_text()
    start = text.index('format="binary">') + len('format="binary">') + 5
    path.write_text(text[:start] + "!!" + text[start + 2:])
    one_line_error(path, "bad base64 data")
    path = write_vti(tmp_path / "c.vti", pattern(), fmt="appended", encoding="base64")
    raw = path.read_bytes()
    cut = appended_start(raw) + 19
    path.write_bytes(raw[:cut] + b"#" + raw[cut + 1:])
    one_line_error(path, "bad base64 data")


def test_zlib_error(tmp_path: Path) -> None:
    path = write_vti(tmp_path / "z.vti", pattern(), fmt="appended", encoding="raw", compress=True, block=10_000)
    raw = bytearray(path.read_bytes())
    first_block = appended_start(raw) + 4 * 4  # header: nb, bs, lbs, cs0 (UInt32)
    raw[first_block + 5:first_block + 15] = b"\xff" * 10
    path.write_bytes(bytes(raw))
    one_line_error(path, "zlib error in block 0")


def test_data_shorter_than_the_extent(tmp_path: Path) -> None:
    data = pattern()
    # the data say fewer values than the extent needs (an ascii list, a binary header, zlib blocks)
    for fmt, compress in (("ascii", False), ("binary", False), ("appended", False), ("appended", True)):
        path = write_vti(tmp_path / f"s_{fmt}{compress}.vti", data[:, :, :-1], fmt=fmt, compress=compress)
        text = path.read_bytes().replace(b'Extent="2 6 0 6 -3 4"', b'Extent="2 6 0 6 -3 5"')
        path.write_bytes(text)
        msg = one_line_error(path, "data shorter than the extent")
        assert f"{NX}x{NY}x{NZ}" in msg
    # a file cut inside its appended data
    path = write_vti(tmp_path / "cut.vti", data, fmt="appended", encoding="raw")
    raw = path.read_bytes()
    path.write_bytes(raw[:appended_start(raw) + 4 + 100])
    one_line_error(path, "truncated")
    path = write_vti(tmp_path / "cut64.vti", data, fmt="appended", encoding="base64")
    raw = path.read_bytes()
    path.write_bytes(raw[:appended_start(raw) + 400])
    one_line_error(path, "truncated")


def test_unsupported_variants(tmp_path: Path) -> None:
    path = write_vti(tmp_path / "r.vti", pattern(), dataset="RectilinearGrid")
    one_line_error(path, "VTK dataset type 'RectilinearGrid' is not read; only ImageData")
    vec = np.stack([pattern()] * 3, axis=-1)
    path = write_vti(tmp_path / "v.vti", vec, components=3)
    one_line_error(path, "array 'density' has 3 components; only scalar arrays are read")
    path = write_vti(tmp_path / "l.vti", pattern(), fmt="binary", compress=True)
    path.write_bytes(path.read_bytes().replace(b"vtkZLibDataCompressor", b"vtkLZ4DataCompressor"))
    one_line_error(path, "compressor 'vtkLZ4DataCompressor' is not read")
    path = write_vti(tmp_path / "p.vti", pattern(), fmt="ascii")
    text = path.read_text()
    piece = text[text.index("<Piece"):text.index("</Piece>") + len("</Piece>")]
    path.write_text(text.replace(piece, piece + piece))
    one_line_error(path, "has 2 <Piece> elements")


def test_array_option_only_for_vti(tmp_path: Path) -> None:
    path = tmp_path / "a.npy"
    np.save(path, pattern())
    one_line_error(path, "array only applies to .vti files", array="density")
