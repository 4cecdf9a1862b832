"""The engine's public API is typed: every public function and method of the bodies and the mesh and
geometry modules annotates its parameters and return value (numba kernels are typed in their docstrings)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ENGINE = Path(__file__).resolve().parents[1] / "systems" / "engine"
TYPED = sorted([*ENGINE.glob("*.py"), *(ENGINE / "bodies").glob("*.py")])


def _untyped(path: Path) -> list[str]:
    out = []
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if not isinstance(node, ast.FunctionDef) or (node.name.startswith("_") and node.name != "__init__"):
            continue
        if any("njit" in ast.unparse(d) for d in node.decorator_list):
            continue
        args = node.args.args + node.args.kwonlyargs
        missing = [a.arg for a in args if a.annotation is None and a.arg not in ("self", "cls")]
        if node.args.vararg is not None and node.args.vararg.annotation is None:
            missing.append("*" + node.args.vararg.arg)
        if node.args.kwarg is not None and node.args.kwarg.annotation is None:
            missing.append("**" + node.args.kwarg.arg)
        if missing or (node.returns is None and node.name != "__init__"):
            out.append(f"{path.name}:{node.lineno} {node.name} {missing}")
    return out


@pytest.mark.parametrize("path", TYPED, ids=[p.relative_to(ENGINE).as_posix() for p in TYPED])
def test_public_functions_are_typed(path):
    assert _untyped(path) == []


def test_the_researchers_names_come_from_the_engine_package():
    import chainsim.systems.engine as engine
    from chainsim.systems.engine.bodies.factory import make_body
    from chainsim.systems.engine.meshgen import tet_grid

    assert engine.make_body is make_body and engine.tet_grid is tet_grid
    assert set(engine.__all__) == {"make_body", "tet_grid"}
    with pytest.raises(AttributeError, match="no attribute 'make_bodies'"):
        engine.make_bodies  # noqa: B018 - a misspelt name fails as a missing attribute does
