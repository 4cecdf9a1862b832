"""No function in the program's packages grows past LIMIT lines without being named here.

A function longer than a screen or so is read by scrolling and remembering; past LIMIT lines
(`def` to its last line, docstring included) it is split into named functions. The few left longer
are listed in ALLOWED with why, each capped at the length it has, so none of them grows silently and
the list only shrinks: an entry for a function now within LIMIT, or gone, fails too.
"""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("components", "systems", "game", "tools")
LIMIT = 80

_KERNEL = "numba kernel: one compiled loop over its work queue and the state it carries"

#: "path::qualified name": (most lines, why it is longer than LIMIT)
ALLOWED: dict[str, tuple[int, str]] = {
    # engine kernels (@njit): each loop carries its queues and counters through one frame; they are
    # timed by the benchmarks and checked against the plain-Python references in tests/kernels, and
    # change only with those
    "systems/engine/kernels/exact.py::_walk": (181, _KERNEL),
    "systems/engine/kernels/exact.py::_exact": (178, _KERNEL),
    "systems/engine/kernels/exact.py::_closure_walk3": (163, _KERNEL),
    "systems/engine/kernels/exact.py::_exact_move": (150, _KERNEL),
    "systems/engine/kernels/exact.py::_closure_walk_nd": (122, _KERNEL),
    "systems/engine/kernels/exact.py::_reach": (109, _KERNEL),
    "systems/engine/kernels/exact.py::_settle_targets": (94, _KERNEL),
    "systems/engine/kernels/chainmail.py::_fifo_loop_3d": (103, _KERNEL),
    "systems/engine/kernels/chainmail.py::_cascade_balanced": (87, _KERNEL),
    "systems/engine/kernels/gibson.py::_grid_kernel": (93, _KERNEL),
    # body models: a solver step or constructor that sets up one model's arrays in order
    "systems/engine/bodies/chainmail.py::ChainMailBody.move": (102, "to split: grab, cascade, relax, limits"),
    "systems/engine/bodies/xpbd.py::XPBDBody.__init__": (91, "to split: XPBD constraint setup"),
    "systems/engine/bodies/projective.py::ProjectiveBody.__init__": (88, "to split: projective system setup"),
    # pack-building scripts: one recipe read top to bottom, run once when the pack's data is rebuilt
    "game/packbuild/needle/prepare_prp.py::build": (160, "pack build recipe, run once"),
    "game/packbuild/needle/prepare_prp.py::fit_skin": (87, "pack build recipe, run once"),
    "game/packbuild/needle/make_prp_scripts.py::main": (125, "pack build recipe, run once"),
    # benchmark drivers: the timed sequence in one place, so what is measured is read at once
    "tools/bench/window.py::run": (121, "benchmark driver: the timed sequence"),
    "tools/bench/render.py::run_sheets": (118, "benchmark driver: the timed sequence"),
    "tools/bench/render.py::run_pack": (99, "benchmark driver: the timed sequence"),
    "tools/bench/records.py::run_bench": (98, "benchmark driver: the timed sequence"),
    # not split yet
}


def _functions(tree: ast.AST, prefix: str = ""):
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, ast.ClassDef):
            yield from _functions(node, f"{prefix}{node.name}.")
        elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            yield f"{prefix}{node.name}", node.end_lineno - node.lineno + 1
            yield from _functions(node, f"{prefix}{node.name}.")
        else:
            yield from _functions(node, prefix)


def function_lengths() -> dict[str, int]:
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            for name, lines in _functions(ast.parse(path.read_text(encoding="utf-8"), rel)):
                out[f"{rel}::{name}"] = max(lines, out.get(f"{rel}::{name}", 0))
    return out


def test_no_function_is_longer_than_the_limit_unless_listed_and_none_listed_grew():
    lengths = function_lengths()
    assert len(lengths) > 1000  # the walk found the packages
    too_long = [
        f"{key}: {n} lines (limit {LIMIT}{f', listed at {ALLOWED[key][0]}' if key in ALLOWED else ''})"
        for key, n in sorted(lengths.items())
        if n > LIMIT and n > ALLOWED.get(key, (LIMIT, ""))[0]
    ]
    assert not too_long, "split these into named functions:\n" + "\n".join(too_long)


def test_the_allow_list_names_only_functions_still_over_the_limit():
    lengths = function_lengths()
    stale = [
        f"{key}: {'gone' if key not in lengths else f'{lengths[key]} lines now'}; take it off ALLOWED"
        for key in ALLOWED
        if lengths.get(key, 0) <= LIMIT
    ]
    assert not stale, "\n".join(stale)


def test_the_check_sees_a_long_function(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(LIMIT))
    tree = ast.parse(f"class A:\n    def f(self):\n{body.replace('    ', '        ')}\n\ndef g():\n    pass\n")
    assert dict(_functions(tree)) == {"A.f": LIMIT + 1, "g": 2}
