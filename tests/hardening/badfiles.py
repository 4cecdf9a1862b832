"""Writers of hostile mesh files: decompression bombs, lying headers, non-finite and huge coordinates.

Each builds its file in a few kilobytes of memory however large the data it declares or expands to.
"""

from __future__ import annotations

import base64
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np

ZERO_CHUNK = bytes(1 << 20)


def obj(path: Path, vertices: list[str], faces=((1, 2, 3),)) -> Path:
    """An OBJ with the vertex lines given as text (so 'nan', '1e309' reach the parser verbatim)."""
    lines = [f"v {v}" for v in vertices] + [f"f {' '.join(map(str, f))}" for f in faces]
    path.write_text("\n".join(lines) + "\n")
    return path


def npz_bomb(path: Path, expanded_bytes: int, *, declared_rows: int | None = None) -> Path:
    """An .npz whose 'positions' expand to `expanded_bytes` of zeros (a valid .npy header, float64 N x 3)."""
    rows = declared_rows if declared_rows is not None else expanded_bytes // 24
    header = {"descr": "<f8", "fortran_order": False, "shape": (rows, 3)}
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        with zf.open("positions.npy", "w", force_zip64=True) as fh:
            np.lib.format.write_array_header_1_0(fh, header)
            left = expanded_bytes
            while left > 0:
                n = min(left, len(ZERO_CHUNK))
                fh.write(ZERO_CHUNK[:n])
                left -= n
        with zf.open("links.npy", "w") as fh:
            np.lib.format.write_array(fh, np.array([[0, 1]], dtype=np.int64))
    return path


def npz_lying_header(path: Path, rows: int) -> Path:
    """An .npz whose positions header declares `rows` rows but holds one."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        with zf.open("positions.npy", "w") as fh:
            np.lib.format.write_array_header_1_0(fh, {"descr": "<f8", "fortran_order": False, "shape": (rows, 3)})
            fh.write(bytes(24))
        with zf.open("links.npy", "w") as fh:
            np.lib.format.write_array(fh, np.zeros((0, 2), dtype=np.int64))
    return path


def npz_arrays(path: Path, **arrays) -> Path:
    np.savez(path, **arrays)
    return path


def _zlib_stream(n: int) -> bytes:
    c = zlib.compressobj(9)
    out = []
    left = n
    while left > 0:
        k = min(left, len(ZERO_CHUNK))
        out.append(c.compress(ZERO_CHUNK[:k]))
        left -= k
    out.append(c.flush())
    return b"".join(out)


def _cells_xml() -> str:
    conn = " ".join(map(str, range(4)))
    return (
        '<Cells>\n<DataArray type="Int64" Name="connectivity" format="ascii">' + conn + "</DataArray>\n"
        '<DataArray type="Int64" Name="offsets" format="ascii">4</DataArray>\n'
        '<DataArray type="UInt8" Name="types" format="ascii">10</DataArray>\n</Cells>\n'
    )


def vtu_bomb(
    path: Path,
    expanded_bytes: int,
    *,
    points: int | None = None,
    declared_block: int | None = None,
    appended_raw: bool = False,
) -> Path:
    """A zlib-compressed .vtu whose Points array expands to `expanded_bytes` of zeros.

    points: the NumberOfPoints written (default: what the data holds); declared_block: the block
    size its header declares (default: the truth; smaller = a header that lies); appended_raw: the
    data in a raw <AppendedData> section instead of inline base64.
    """
    n_points = points if points is not None else max(4, expanded_bytes // 24)
    data = _zlib_stream(expanded_bytes)
    block = declared_block if declared_block is not None else expanded_bytes
    header = struct.pack("<4I", 1, block, block, len(data))
    head = (
        '<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian" '
        'header_type="UInt32" compressor="vtkZLibDataCompressor">\n<UnstructuredGrid>\n'
        f'<Piece NumberOfPoints="{n_points}" NumberOfCells="1">\n<Points>\n'
    )
    if appended_raw:
        body = (
            head
            + '<DataArray type="Float64" Name="Points" NumberOfComponents="3" format="appended" offset="0"/>\n'
            + "</Points>\n"
            + _cells_xml()
            + '</Piece>\n</UnstructuredGrid>\n<AppendedData encoding="raw">\n_'
        ).encode()
        path.write_bytes(body + header + data + b"\n</AppendedData>\n</VTKFile>\n")
    else:
        b64 = base64.b64encode(header).decode() + base64.b64encode(data).decode()
        text = (
            head
            + '<DataArray type="Float64" Name="Points" NumberOfComponents="3" format="binary">\n'
            + b64
            + "\n</DataArray>\n</Points>\n"
            + _cells_xml()
            + "</Piece>\n</UnstructuredGrid>\n</VTKFile>\n"
        )
        path.write_text(text)
    return path


def ply_declaring(path: Path, vertices: int, faces: int = 1) -> Path:
    """An ASCII PLY whose header declares `vertices` vertices but whose body holds three."""
    path.write_text(
        "ply\nformat ascii 1.0\n"
        f"element vertex {vertices}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {faces}\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    )
    return path
