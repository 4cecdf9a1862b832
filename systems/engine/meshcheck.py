"""Checks on a mesh file before any parser reads it: declared counts and declared (and real) data sizes.

A small file can declare a huge mesh: a 1 MB .npz whose arrays expand to gigabytes, a .vtu whose
zlib blocks do, a PLY header announcing 10^12 vertices. The file-size limit alone cannot see that,
so each format's own headers are read first, cheaply, and the file is refused when what it declares
is over the limits of chainsim.systems.engine.limits (MAX_VERTICES, MAX_CELLS, the mesh size limit):

    .npz    zip directory (uncompressed sizes) and each .npy header (dtype, shape)
    .vtu    NumberOfPoints / NumberOfCells, and every compressed block's declared size, verified by
            decompressing with a bound (a block that expands past what it declares is refused)
    .ply .off .vtk .msh .mesh    element counts in their headers
    .gltf .glb                   buffers and images must be embedded or inside the mesh's folder

Every check raises MeshCheckError(message) with no file prefix; the loaders add it.
"""

from __future__ import annotations

import base64
import json
import lzma
import re
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np

from chainsim.systems.engine import limits


class MeshCheckError(ValueError):
    """What a mesh file declares is unusable or over a limit; the message says which."""


def _mb(n: int) -> str:
    return f"{n / 1048576:.3g} MB"


def _counts(what: str, n: int, limit: int) -> None:
    if n > limit:
        raise MeshCheckError(f"declares {n:,} {what}, over the {limit:,} limit (docs/limits.md)")


# -- .npz ----------------------------------------------------------------------------------------


def check_npz(path: Path, max_bytes: int) -> None:
    """Zip directory and .npy headers of an .npz: no pickles, declared arrays within `max_bytes`."""
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as e:
        raise MeshCheckError(f"not a readable .npz file ({type(e).__name__})") from None
    with zf:
        infos = zf.infolist()
        if len(infos) > 64:
            raise MeshCheckError(f"holds {len(infos)} arrays; a mesh .npz has positions, links and fixed")
        total = sum(i.file_size for i in infos)
        if total > max_bytes:
            raise MeshCheckError(
                f"its arrays expand to {_mb(total)}, over the {_mb(max_bytes)} mesh limit (CHAINSIM_MAX_MESH_MB)"
            )
        data = 0
        for info in infos:
            if not info.filename.endswith(".npy"):
                continue
            name = info.filename[:-4]
            try:
                with zf.open(info) as fh:
                    version = np.lib.format.read_magic(fh)
                    if version == (1, 0):
                        shape, _, dtype = np.lib.format.read_array_header_1_0(fh, max_header_size=10000)
                    else:
                        shape, _, dtype = np.lib.format.read_array_header_2_0(fh, max_header_size=10000)
            except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error, NotImplementedError) as e:
                raise MeshCheckError(f"array '{name}' has no readable .npy header ({type(e).__name__})") from None
            if dtype.hasobject:
                raise MeshCheckError(f"array '{name}' holds Python objects; expected numbers")
            nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
            if nbytes > info.file_size:
                raise MeshCheckError(f"array '{name}' declares shape {shape} but the file holds less data")
            data += nbytes
            rows = int(shape[0]) if len(shape) else 1
            if name == "positions":
                _counts("positions", rows, limits.MAX_VERTICES)
            elif name in ("links", "fixed"):
                _counts(name, rows, limits.MAX_CELLS)
        if data > max_bytes:
            raise MeshCheckError(f"its arrays hold {_mb(data)}, over the {_mb(max_bytes)} mesh limit")


# -- .vtu ----------------------------------------------------------------------------------------

_HEADER_TYPES = {"UInt32": "I", "UInt64": "Q", "Int32": "i", "Int64": "q"}
_ATTR = re.compile(rb'([A-Za-z_:][\w:.-]*)\s*=\s*"([^"]*)"')


def _attrs(tag: bytes) -> dict[str, str]:
    return {k.decode(): v.decode("utf-8", "replace") for k, v in _ATTR.findall(tag)}


class _Blocks:
    """Compressed VTK data: header [nblocks, block size, last block size, compressed sizes...]."""

    def __init__(self, compressor: str, fmt: str, order: str, max_bytes: int):
        self.decomp = {"vtkZLibDataCompressor": "zlib", "vtkLZMADataCompressor": "lzma"}.get(compressor)
        if self.decomp is None:
            raise MeshCheckError(f"compressor {compressor!r} is not supported; use zlib or lzma")
        self.fmt, self.order, self.size = fmt, order, struct.calcsize(fmt)
        self.max_bytes, self.total = max_bytes, 0

    def _header(self, raw: bytes) -> tuple[int, int, int, list[int], int]:
        if len(raw) < 3 * self.size:
            raise MeshCheckError("a compressed data array has a truncated header")
        nblocks, bsize, last = struct.unpack_from(f"{self.order}3{self.fmt}", raw)
        if min(nblocks, bsize, last) < 0 or nblocks > limits.MAX_CELLS:
            raise MeshCheckError(f"a compressed data array declares {nblocks:,} blocks of {bsize:,} bytes")
        if bsize > self.max_bytes:
            raise MeshCheckError(
                f"a compressed data array declares blocks of {_mb(bsize)}, over the {_mb(self.max_bytes)} "
                "mesh limit (CHAINSIM_MAX_MESH_MB)"
            )
        hlen = (3 + nblocks) * self.size
        if len(raw) < hlen:
            raise MeshCheckError("a compressed data array has a truncated header")
        sizes = list(struct.unpack_from(f"{self.order}{nblocks}{self.fmt}", raw, 3 * self.size))
        return nblocks, bsize, last, sizes, hlen

    def verify_raw(self, raw: bytes) -> None:
        """Header and compressed blocks stored one after the other as bytes (appended raw data)."""
        nblocks, bsize, last, sizes, hlen = self._header(raw)
        self._blocks(nblocks, bsize, last, sizes, raw[hlen:])

    def verify_base64(self, text: bytes) -> None:
        """Header and blocks as two base64 runs, as VTK writes them (inline or appended base64 data)."""
        text = b"".join(text.split())
        first = _b64(text[: _chars(self.size)])
        if len(first) < self.size:
            raise MeshCheckError("a compressed data array has a truncated header")
        (nblocks,) = struct.unpack_from(f"{self.order}{self.fmt}", first)
        if not 0 <= nblocks <= limits.MAX_CELLS:
            raise MeshCheckError(f"a compressed data array declares {nblocks:,} blocks")
        hchars = _chars((3 + nblocks) * self.size)
        nblocks, bsize, last, sizes, _ = self._header(_b64(text[:hchars]))
        self._blocks(nblocks, bsize, last, sizes, _b64(text[hchars:]))

    def _blocks(self, nblocks: int, bsize: int, last: int, sizes: list[int], data: bytes) -> None:
        declared = nblocks * bsize if last == 0 or nblocks == 0 else (nblocks - 1) * bsize + last
        self.total += declared
        if self.total > self.max_bytes:
            raise MeshCheckError(
                f"its compressed arrays expand to over {_mb(self.total)}, over the {_mb(self.max_bytes)} "
                "mesh limit (CHAINSIM_MAX_MESH_MB)"
            )
        pos = 0
        for k, csize in enumerate(sizes):
            want = bsize if (k < nblocks - 1 or last == 0) else last
            chunk = data[pos : pos + csize]
            pos += csize
            d = zlib.decompressobj() if self.decomp == "zlib" else lzma.LZMADecompressor()
            try:
                out = d.decompress(chunk, want + 1)
            except (zlib.error, lzma.LZMAError) as e:
                raise MeshCheckError(f"a compressed block is damaged ({e})") from None
            if len(out) > want:
                raise MeshCheckError(f"a compressed block expands past the {want:,} bytes it declares")


def _chars(nbytes: int) -> int:
    """Base64 characters that encode `nbytes` bytes (padded)."""
    return -(-nbytes // 3) * 4


def _b64(text: bytes) -> bytes:
    try:
        return base64.b64decode(b"".join(text.split()), validate=False)
    except (ValueError, TypeError):
        raise MeshCheckError("a binary data array is not valid base64") from None


def check_vtu(path: Path, max_bytes: int) -> None:
    """Declared point/cell counts and every compressed block of a VTK XML unstructured grid."""
    raw = path.read_bytes()
    head = raw[:4096]
    if b"<!DOCTYPE" in head or b"<!ENTITY" in raw[:65536]:
        raise MeshCheckError("XML document types and entities are not allowed in a .vtu file")
    vtk = re.search(rb"<VTKFile\b[^>]*>", raw)
    if vtk is None:
        raise MeshCheckError("no <VTKFile> element; not a VTK XML file")
    top = _attrs(vtk.group())
    for m in re.finditer(rb"<Piece\b[^>]*>", raw):
        a = _attrs(m.group())
        for key, what, limit in (
            ("NumberOfPoints", "points", limits.MAX_VERTICES),
            ("NumberOfCells", "cells", limits.MAX_CELLS),
        ):
            try:
                n = int(a.get(key, "0"))
            except ValueError:
                raise MeshCheckError(f"{key}={a.get(key)!r} is not a whole number") from None
            _counts(what, n, limit)
    compressor = top.get("compressor")
    if not compressor:
        return  # uncompressed data cannot be larger than the file, which is already within the limit
    fmt = _HEADER_TYPES.get(top.get("header_type", "UInt32"))
    if fmt is None:
        raise MeshCheckError(f"header_type {top.get('header_type')!r} is not supported")
    order = ">" if top.get("byte_order") == "BigEndian" else "<"
    blocks = _Blocks(compressor, fmt, order, max_bytes)
    for m in re.finditer(rb"<DataArray\b([^>]*)>(.*?)</DataArray>", raw, re.S):
        if _attrs(m.group(1)).get("format") == "binary":
            blocks.verify_base64(m.group(2))
    app = re.search(rb"<AppendedData\b([^>]*)>", raw)
    if app is None:
        return
    enc = _attrs(app.group(1)).get("encoding", "raw")
    start = raw.find(b"_", app.end())
    stop = raw.rfind(b"</AppendedData>")
    if start < 0 or stop < start:
        raise MeshCheckError("the <AppendedData> section has no data")
    data = raw[start + 1 : stop]
    offsets = sorted(
        {
            int(a["offset"])
            for a in (_attrs(t) for t in re.findall(rb"<DataArray\b[^>]*>", raw))
            if a.get("format") == "appended" and a.get("offset", "").isdigit()
        }
    )
    for off in offsets:
        if enc == "base64":
            blocks.verify_base64(data[off:].split(b"<", 1)[0])
        else:
            blocks.verify_raw(data[off:])


# -- text headers: .ply .off .vtk .msh .mesh ------------------------------------------------------

_HEADER_COUNTS = {
    ".ply": [(rb"(?m)^element\s+vertex\s+(\d+)", "vertices", "v"), (rb"(?m)^element\s+face\s+(\d+)", "faces", "c")],
    ".vtk": [(rb"(?m)^POINTS\s+(\d+)", "points", "v"), (rb"(?m)^CELLS\s+(\d+)", "cells", "c")],
    ".mesh": [
        (rb"(?m)^\s*Vertices\s+(\d+)", "vertices", "v"),
        (rb"(?m)^\s*(?:Triangles|Tetrahedra|Edges|Quadrilaterals)\s+(\d+)", "cells", "c"),
    ],
    ".msh": [
        (rb"\$Nodes\s+(?:\d+\s+)?(\d+)", "nodes", "v"),
        (rb"\$Elements\s+(?:\d+\s+)?(\d+)", "elements", "c"),
    ],
}


def check_text_headers(path: Path, ext: str) -> None:
    """Element counts declared in the header lines of PLY, OFF, legacy VTK, Gmsh and Medit files."""
    with path.open("rb") as fh:
        raw = fh.read()
    if ext == ".off":
        m = re.match(rb"\s*[A-Z]*OFF\s+(?:#[^\n]*\s+)*(\d+)\s+(\d+)", raw)
        if m:
            _counts("vertices", int(m.group(1)), limits.MAX_VERTICES)
            _counts("faces", int(m.group(2)), limits.MAX_CELLS)
        return
    head = raw[:65536] if ext == ".ply" else raw
    for pattern, what, kind in _HEADER_COUNTS.get(ext, []):
        for m in re.finditer(pattern, head):
            n = int(m.group(1)) if len(m.group(1)) < 20 else 10**20
            _counts(what, n, limits.MAX_VERTICES if kind == "v" else limits.MAX_CELLS)


# -- glTF ----------------------------------------------------------------------------------------


def _gltf_json(path: Path, ext: str) -> dict:
    raw = path.read_bytes()
    if ext == ".glb":
        if len(raw) < 20 or raw[:4] != b"glTF":
            raise MeshCheckError("not a binary glTF file (no glTF header)")
        (length,) = struct.unpack_from("<I", raw, 12)
        if raw[16:20] != b"JSON" or length > len(raw) - 20:
            raise MeshCheckError("binary glTF without a readable JSON chunk")
        raw = raw[20 : 20 + length]
    depth = deepest = 0
    for m in re.finditer(rb'"(?:[^"\\]|\\.)*"|[\[\]{}]', raw):
        c = m.group()
        if c in (b"[", b"{"):
            depth += 1
            deepest = max(deepest, depth)
        elif c in (b"]", b"}"):
            depth -= 1
    if deepest > limits.MAX_NESTING:
        raise MeshCheckError(f"its JSON is nested more than {limits.MAX_NESTING} levels deep")
    try:
        data = json.loads(raw)
    except (ValueError, RecursionError) as e:
        raise MeshCheckError(f"its glTF JSON is not readable ({type(e).__name__})") from None
    if not isinstance(data, dict):
        raise MeshCheckError("its glTF JSON is not an object")
    return data


def check_gltf(path: Path, ext: str) -> None:
    """Buffers and images must be embedded (data: URIs, the GLB chunk) or files inside the mesh's folder."""
    data = _gltf_json(path, ext)
    folder = path.parent.resolve()
    for section in ("buffers", "images"):
        items = data.get(section, [])
        if not isinstance(items, list):
            raise MeshCheckError(f"'{section}' is not an array")
        for item in items:
            uri = item.get("uri") if isinstance(item, dict) else None
            if not isinstance(uri, str) or uri.startswith("data:"):
                continue
            if "\x00" in uri or "://" in uri or uri.startswith(("/", "\\")) or re.match(r"^[A-Za-z]:", uri):
                raise MeshCheckError(f"{section} uri {uri[:60]!r} must be a file next to the mesh or embedded")
            target = (folder / uri).resolve()
            if not target.is_relative_to(folder):
                raise MeshCheckError(f"{section} uri {uri[:60]!r} escapes the mesh's folder")


def check_file(path: Path, ext: str, max_bytes: int) -> None:
    """Run the checks for `ext` (a lower-case suffix); raises MeshCheckError."""
    try:
        if ext == ".npz":
            check_npz(path, max_bytes)
        elif ext == ".vtu":
            check_vtu(path, max_bytes)
        elif ext in (".gltf", ".glb"):
            check_gltf(path, ext)
        elif ext in (".ply", ".off", ".vtk", ".msh", ".mesh"):
            check_text_headers(path, ext)
    except OSError as e:
        raise MeshCheckError(f"cannot read ({e.strerror or e})") from None
