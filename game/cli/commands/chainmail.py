"""`chainsim chainmail`: one Generalised ChainMail move on a mesh file, for conformance checks (thesis 5.2).

    chainsim chainmail MESH --grab I --to X [Y [Z]] --alpha-min A --alpha-max B --beta C
                       [--relax N] [--order fifo|balanced|schill] [--fixed-as-given] --out OUT.npz

MESH is a .npz (positions (N, D), links (M, 2), optional fixed (K,)) or any mesh file the importer
reads (chainsim.engine.meshimport). OUT.npz holds positions (N, D) after the move, order (the ids that moved, in
the order they moved, grabbed first, each once) and sponsor (N,: the element whose move made each
element move; -1 for the grabbed element and for elements that did not move). --relax 0 gives the raw
cascade; N > 0 runs N relaxation sweeps (5.2.5) over the moved elements afterwards.

Every input is checked before anything runs; a bad one is a one-line error (exit 2) and nothing is
written. The result is written to a temporary file and renamed into place only when complete.
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np

from chainsim.engine.chainmail_params import ORDERS, check_material
from chainsim.engine.errors import UserError
from chainsim.engine.kernels.chainmail import (
    ORDER_BALANCED,
    ORDER_FIFO,
    ORDER_SCHILL,
    cascade,
    make_workspace,
    material_arrays,
)
from chainsim.engine.kernels.graph import build_graph
from chainsim.engine.meshimport import load_graph
from chainsim.systems.deformation import relax_moved

NAME = "chainmail"
HELP = "move one element of a mesh with Generalised ChainMail and save the result (.npz)"


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP, description=HELP)
    p.add_argument(
        "mesh", metavar="MESH", help=".npz with positions/links[/fixed], or a mesh file (.obj .ply .stl .msh .vtu ...)"
    )
    p.add_argument("--grab", type=int, required=True, metavar="I", help="id of the element to move")
    p.add_argument("--to", type=float, nargs="+", required=True, metavar="X", help="target position: D coordinates")
    p.add_argument("--alpha-min", type=float, required=True, metavar="A", help="compression limit in [0, 1]")
    p.add_argument("--alpha-max", type=float, required=True, metavar="B", help="stretch limit >= 1")
    p.add_argument("--beta", type=float, required=True, metavar="C", help="shear limit >= 0")
    p.add_argument(
        "--relax", type=int, default=0, metavar="N", help="relaxation sweeps after the cascade (default 0: raw cascade)"
    )
    p.add_argument("--relax-step", type=float, default=1.0, metavar="S", help="relaxation step in (0, 1] (default 1)")
    p.add_argument("--order", choices=ORDERS, default="fifo", help="waiting-list order (default fifo)")
    p.add_argument(
        "--kind",
        choices=("auto", "surface", "volume"),
        default="auto",
        help="for mesh files: surface links, tetrahedron links (closed surfaces are filled), or as the file is",
    )
    p.add_argument("--out", required=True, metavar="OUT.npz", help="result file (written atomically)")
    return p


def _finite(name: str, v: float) -> None:
    if not math.isfinite(v):
        raise UserError(f"{name}: must be a finite number, got {v}")


def check_material_flags(args) -> None:
    """--alpha-min in [0, 1], --alpha-max >= 1, --beta >= 0, all finite (thesis 5.2.2)."""
    check_material(args.alpha_min, args.alpha_max, args.beta)


def check_args(args) -> None:
    """Checks that need no mesh (so a bad flag costs nothing)."""

    check_material_flags(args)
    _finite("--relax-step", args.relax_step)
    for v in args.to:
        _finite("--to", v)
    if args.relax < 0:
        raise UserError(f"--relax: must be >= 0, got {args.relax}")
    if not 0.0 < args.relax_step <= 1.0:
        raise UserError(f"--relax-step: must be in (0, 1], got {args.relax_step:g}")
    if len(args.to) > 3:
        raise UserError(f"--to: expected 1 to 3 coordinates, got {len(args.to)}")
    out = Path(args.out)
    if out.suffix.lower() != ".npz":
        raise UserError(f"--out: must name a .npz file, got {args.out}")
    parent = out.parent if str(out.parent) else Path(".")
    if not parent.is_dir():
        raise UserError(f"--out: folder {parent} does not exist")


def simulate(
    positions, links, fixed_ids, grab: int, target, alpha_min, alpha_max, beta, relax_n=0, relax_step=1.0, order="fifo"
):
    """Run one move; returns (positions, order, sponsor (N,))."""

    pos = np.array(positions, dtype=np.float64, copy=True, order="C")
    rest = np.array(positions, dtype=np.float64, copy=True, order="C")
    n = len(pos)
    graph = build_graph(n, links)
    amin, amax, bet = material_arrays(graph.n_links, alpha_min, alpha_max, beta)
    fixed = None
    if len(fixed_ids):
        fixed = np.zeros(n, dtype=np.bool_)
        fixed[fixed_ids] = True
    code = {"fifo": ORDER_FIFO, "balanced": ORDER_BALANCED, "schill": ORDER_SCHILL}[order]
    moved, sponsors = cascade(
        rest,
        pos,
        graph,
        amin,
        amax,
        bet,
        np.array([grab], dtype=np.int64),
        np.asarray(target, dtype=np.float64).reshape(1, -1),
        fixed=fixed,
        order=code,
        workspace=make_workspace(n),
    )
    if relax_n > 0 and len(moved) > 1:
        pin = np.zeros(n, dtype=np.bool_) if fixed is None else fixed.copy()
        pin[grab] = True  # the user holds the grabbed element where it was put
        relax_moved(rest, pos, graph, moved, relax_n, step=relax_step, fixed=pin)
    sponsor = np.full(n, -1, dtype=np.int64)
    sponsor[moved] = sponsors
    return pos, moved.astype(np.int64), sponsor


def write_result(out: Path, positions, order, sponsor) -> None:
    """Write OUT.npz atomically: a temporary file in the same folder, renamed when complete."""

    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as fh:
            np.savez(fh, positions=positions, order=order, sponsor=sponsor)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, out)
    except OSError as e:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise UserError(f"--out: cannot write {out} ({e.strerror or e})") from None
    finally:
        if tmp.exists():
            tmp.unlink()


def run(args) -> int:

    check_args(args)
    positions, links, fixed = load_graph(args.mesh, kind=args.kind)
    n, dim = positions.shape
    if not 0 <= args.grab < n:
        raise UserError(f"--grab: element id must be in 0..{n - 1}, got {args.grab}")
    if len(args.to) != dim:
        raise UserError(f"--to: the mesh is {dim}-D, so give {dim} coordinate(s); got {len(args.to)}")
    try:
        pos, order, sponsor = simulate(
            positions,
            links,
            fixed,
            args.grab,
            args.to,
            args.alpha_min,
            args.alpha_max,
            args.beta,
            args.relax,
            args.relax_step,
            args.order,
        )
    except ValueError as e:  # the kernels' own checks, if anything slipped past ours
        raise UserError(f"{args.mesh}: {e}") from None
    write_result(Path(args.out), pos, order, sponsor)
    print(f"moved {len(order)} of {n} elements; wrote {args.out}", file=sys.stderr)
    return 0
