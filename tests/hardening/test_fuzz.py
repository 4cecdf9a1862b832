"""Fuzzing the pack loader and the mesh importers: no crash, no hang, nothing non-finite accepted.

Hypothesis draws pack manifests (structured tables with hostile values, and byte-level mutations of
a valid manifest) and mesh files (OBJ, PLY, OFF, VTU, NPZ with random headers, counts and numbers).
The only acceptable outcomes are a clean result or the program's one-line errors (problems from
`validate`, MeshError, UserError); a run longer than PER_EXAMPLE_S seconds fails as a hang.

CI runs CHAINSIM_FUZZ_EXAMPLES examples per test (default 40, about a minute in all). For a
release, run many more:

    CHAINSIM_FUZZ_EXAMPLES=5000 python -m pytest -q tests/hardening/test_fuzz.py
"""

from __future__ import annotations

import base64
import os
import shutil
import signal
import struct
import tempfile
import zlib
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from chainsim.components.registry import COMPONENTS, SECTIONS, load_all
from chainsim.game.trainer.headless import validate_pack
from chainsim.systems.engine import limits
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.meshes import MeshError, load_file
from chainsim.systems.engine.meshimport import load_graph

from .conftest import BASE_PACK

EXAMPLES = int(os.environ.get("CHAINSIM_FUZZ_EXAMPLES", "40"))
PER_EXAMPLE_S = 20
FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.function_scoped_fixture],
)


@contextmanager
def time_limit(seconds: int):
    """Fail the example as a hang if it runs longer than `seconds` (SIGALRM, main thread)."""

    def hang(signum, frame):
        raise TimeoutError(f"example ran past {seconds} s")

    old = signal.signal(signal.SIGALRM, hang)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


@pytest.fixture(scope="module")
def scratch():
    d = Path(tempfile.mkdtemp(prefix="chainsim-fuzz-"))
    yield d
    shutil.rmtree(d, ignore_errors=True)


def _fresh(scratch: Path) -> Path:
    d = Path(tempfile.mkdtemp(dir=scratch))
    return d


# -- values a hostile manifest holds ---------------------------------------------------------------

NUMBERS = st.one_of(
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, -1, 1, 2**31, 2**63 - 1, -(2**63), 1e308, -1e308, 5e-324, 1e6, 1e6 + 1]),
)
TEXT = st.one_of(
    st.text(max_size=20),
    st.sampled_from(
        [
            "",
            "\x00",
            "a\x00b",
            "../../etc/passwd",
            "/etc/passwd",
            "\u202eevil",
            "meshes/m.obj",
            "box",
            "grid",
            "tet_block",
            "sphere",
            "prp",
            "cutting",
            "main",
            "body",
            "soft",
            "sheet",
            "x" * 300,
        ]
    ),
)
SCALAR = st.one_of(NUMBERS, TEXT, st.booleans())
VALUE = st.recursive(
    SCALAR,
    lambda inner: st.one_of(st.lists(inner, max_size=5), st.dictionaries(TEXT, inner, max_size=4)),
    max_leaves=12,
)


def _known_keys():
    load_all()
    keys = set()
    for schema in list(SECTIONS.values()) + list(COMPONENTS.values()):
        keys.update(f.name for f in schema.fields)
    return sorted(keys)


KEYS = st.one_of(st.sampled_from(_known_keys()), TEXT)
TABLE = st.dictionaries(KEYS, VALUE, max_size=6)


@st.composite
def manifests(draw) -> dict:
    """A manifest-shaped dict: real section and component names with hostile tables."""
    load_all()
    man: dict = {"pack": {"name": "fz", "format": 1, **draw(st.dictionaries(KEYS, VALUE, max_size=3))}}
    for sec in draw(st.lists(st.sampled_from(sorted(SECTIONS)), max_size=4, unique=True)):
        if sec == "pack":
            continue
        if sec in ("steps",):
            man[sec] = draw(st.lists(TABLE, max_size=3))
        elif sec == "settings":
            man[sec] = draw(TABLE)
        else:
            man[sec] = draw(st.dictionaries(st.sampled_from(["sheet", "soft", "main", "body", "x"]), TABLE, max_size=3))
    ents = {}
    for name in draw(st.lists(st.sampled_from(["body", "tool", "e"]), max_size=2, unique=True)):
        comps = draw(st.lists(st.sampled_from(sorted(COMPONENTS)), max_size=3, unique=True))
        ents[name] = {c: draw(TABLE) for c in comps}
    if ents:
        man["entities"] = ents
    return man


def _toml(man: dict) -> str | None:
    try:
        return tomli_w.dumps(man)
    except (TypeError, ValueError):  # values TOML cannot hold (e.g. None inside arrays)
        return None


def _check_validate(folder: Path) -> None:
    with time_limit(PER_EXAMPLE_S):
        pack, problems = validate_pack(folder)
    assert (pack is None) == bool(problems)
    for p in problems:
        assert "\n" not in str(p) and str(p).strip()
    if pack is not None:
        for name in pack.manifest["meshes"]:
            v = pack.mesh(name).vertices
            assert np.isfinite(v).all() and np.abs(v).max() <= limits.MAX_COORD


@FUZZ
@given(man=manifests())
def test_fuzzed_manifests_give_problems_or_a_pack(man, scratch):
    text = _toml(man)
    if text is None:
        return
    folder = _fresh(scratch)
    (folder / "pack.toml").write_text(text, encoding="utf-8")
    _check_validate(folder)


MUTATIONS = st.lists(
    st.tuples(
        st.integers(min_value=0, max_value=len(BASE_PACK)),
        st.integers(min_value=0, max_value=8),
        st.one_of(
            st.sampled_from(
                [
                    "[",
                    "]",
                    "{",
                    "}",
                    "=",
                    '"',
                    "'''",
                    "\n",
                    "#",
                    "9" * 30,
                    "1e309",
                    "-",
                    ".",
                    "nan",
                    "inf",
                    "[[",
                    "\\u0000",
                    "]]",
                    ",",
                    "[" * 40,
                ]
            ),
            st.text(max_size=4),
        ),
    ),
    min_size=1,
    max_size=6,
)


@FUZZ
@given(edits=MUTATIONS)
def test_mutated_manifests_give_problems_or_a_pack(edits, scratch):
    text = BASE_PACK
    for pos, cut, insert in edits:
        pos = min(pos, len(text))
        text = text[:pos] + insert + text[pos + cut :]
    folder = _fresh(scratch)
    (folder / "pack.toml").write_text(text, encoding="utf-8", errors="surrogatepass")
    _check_validate(folder)


# -- mesh files ------------------------------------------------------------------------------------

COORD = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["nan", "inf", "-inf", "1e309", "1e308", "-0", "0", "1", "x", "", "1e6", "1000001"]),
)


@st.composite
def obj_text(draw) -> str:
    n = draw(st.integers(0, 8))
    lines = [f"v {draw(COORD)} {draw(COORD)} {draw(COORD)}" for _ in range(n)]
    for _ in range(draw(st.integers(0, 6))):
        idx = draw(st.lists(st.integers(-10, 12), min_size=1, max_size=5))
        lines.append("f " + " ".join(map(str, idx)))
    lines += draw(
        st.lists(st.sampled_from(["vn 0 0 1", "vt 0 0", "o x", "g y", "usemtl m", "mtllib ../../x.mtl"]), max_size=2)
    )
    return "\n".join(draw(st.permutations(lines))) + "\n"


@st.composite
def ply_text(draw) -> str:
    nv = draw(st.one_of(st.integers(0, 6), st.sampled_from([10**7, 10**12, 2**64])))
    nf = draw(st.one_of(st.integers(0, 4), st.sampled_from([10**9, 2**40])))
    body = [f"{draw(COORD)} {draw(COORD)} {draw(COORD)}" for _ in range(draw(st.integers(0, 6)))]
    body += [
        f"3 {draw(st.integers(-2, 8))} {draw(st.integers(-2, 8))} {draw(st.integers(-2, 8))}"
        for _ in range(draw(st.integers(0, 3)))
    ]
    return (
        f"ply\nformat ascii 1.0\nelement vertex {nv}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {nf}\nproperty list uchar int vertex_indices\nend_header\n" + "\n".join(body) + "\n"
    )


@st.composite
def vtu_bytes(draw) -> bytes:
    points = draw(st.one_of(st.integers(0, 10), st.sampled_from([10**7, 2**40])))
    header_type = draw(st.sampled_from(["UInt32", "UInt64", "Int32", "Float64"]))
    fmt = {"UInt32": "<I", "UInt64": "<Q", "Int32": "<i", "Float64": "<I"}[header_type]
    payload = draw(st.binary(max_size=64))
    size = draw(st.one_of(st.just(len(payload)), st.integers(0, 2**31 - 1)))
    comp = zlib.compress(payload)
    nblocks = draw(st.sampled_from([1, 0, 2, 2**31 - 1]))
    head = struct.pack(fmt[0] + fmt[1] * 4, nblocks, size, size, len(comp))
    data = base64.b64encode(head).decode() + base64.b64encode(comp).decode()
    if draw(st.booleans()):
        data = data[: draw(st.integers(0, len(data)))]
    compressor = draw(st.sampled_from(['compressor="vtkZLibDataCompressor"', 'compressor="vtkLZ4DataCompressor"', ""]))
    return (
        f'<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian" '
        f'header_type="{header_type}" {compressor}>\n<UnstructuredGrid>\n<Piece NumberOfPoints="{points}" '
        'NumberOfCells="1">\n<Points>\n<DataArray type="Float64" Name="Points" NumberOfComponents="3" '
        f'format="binary">\n{data}\n</DataArray>\n</Points>\n<Cells>\n'
        '<DataArray type="Int64" Name="connectivity" format="ascii">0 1 2 3</DataArray>\n'
        '<DataArray type="Int64" Name="offsets" format="ascii">4</DataArray>\n'
        '<DataArray type="UInt8" Name="types" format="ascii">10</DataArray>\n</Cells>\n'
        "</Piece>\n</UnstructuredGrid>\n</VTKFile>\n"
    ).encode()


MESH_FILES = st.one_of(
    obj_text().map(lambda t: ("m.obj", t.encode())),
    ply_text().map(lambda t: ("m.ply", t.encode())),
    vtu_bytes().map(lambda b: ("m.vtu", b)),
    st.tuples(
        st.sampled_from(["m.obj", "m.ply", "m.stl", "m.off", "m.vtu", "m.msh", "m.vtk", "m.mesh", "m.glb", "m.gltf"]),
        st.binary(max_size=300),
    ),
    st.tuples(
        st.just("m.off"),
        st.from_regex(r"OFF\n[0-9]{1,14} [0-9]{1,12} 0\n(0 0 0\n){0,3}", fullmatch=True).map(str.encode),
    ),
)


def _check_loaded(vertices) -> None:
    v = np.asarray(vertices)
    assert np.isfinite(v).all()
    assert len(v) == 0 or np.abs(v).max() <= limits.MAX_COORD


@FUZZ
@given(mesh=MESH_FILES)
def test_fuzzed_mesh_files_load_or_raise_one_line(mesh, scratch, monkeypatch):
    monkeypatch.setenv("CHAINSIM_MAX_MESH_MB", "4")
    name, content = mesh
    path = _fresh(scratch) / name
    path.write_bytes(content)
    with time_limit(PER_EXAMPLE_S):
        try:
            m = load_file(path, 1.0, True, label=name)
        except MeshError as e:
            assert "\n" not in str(e) and name in str(e)
        else:
            _check_loaded(m.vertices)
        try:
            pos, links, fixed = load_graph(path)
        except UserError as e:
            assert "\n" not in str(e)
        else:
            _check_loaded(pos)


NPZ_ARRAYS = st.dictionaries(
    st.sampled_from(["positions", "links", "fixed", "extra"]),
    st.one_of(
        st.lists(st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=1, max_size=4), max_size=5).map(
            lambda rows: np.array([r[: min(len(x) for x in rows)] for r in rows]) if rows else np.zeros((0, 3))
        ),
        st.lists(st.lists(st.integers(-(2**62), 2**62), min_size=2, max_size=2), max_size=5).map(
            lambda x: np.array(x, dtype=np.int64).reshape(-1, 2)
        ),
        st.sampled_from(
            [
                np.zeros(3, dtype=np.complex128),
                np.array(["a"]),
                np.zeros((2, 2, 2)),
                np.array([2**63 + 1], dtype=np.uint64),
            ]
        ),
    ),
    max_size=4,
)


@FUZZ
@given(arrays=NPZ_ARRAYS)
def test_fuzzed_npz_graphs_load_or_raise_one_line(arrays, scratch):
    path = _fresh(scratch) / "g.npz"
    np.savez(path, **arrays)
    with time_limit(PER_EXAMPLE_S):
        try:
            pos, links, fixed = load_graph(path)
        except UserError as e:
            assert "\n" not in str(e)
        else:
            _check_loaded(pos)
            assert links.min(initial=0) >= 0 and links.max(initial=-1) < len(pos)
