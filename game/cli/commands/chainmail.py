"""`chainsim chainmail`: one Generalised ChainMail move on a mesh file, for conformance checks (thesis 5.2).

    chainsim chainmail MESH --grab I --to X [Y [Z]] --alpha-min A --alpha-max B --beta C
                       [--relax N] [--order breadth-first|depth-first|balanced|schill] [--exact]
                       [--stats] --out OUT.npz

MESH is a .npz (positions (N, D), links (M, 2), optional fixed (K,)) or any mesh file the importer
reads (chainsim.systems.engine.meshimport). OUT.npz holds positions (N, D) after the move, order (the ids that moved, in
the order they moved, grabbed first, each once) and sponsor (N,: the element whose move made each
element move; -1 for the grabbed element and for elements that did not move). --relax 0 gives the raw
cascade; N > 0 runs N relaxation sweeps (5.2.5) over the moved elements afterwards.

--exact gives the nearest shape with every link inside its limits (chainsim.systems.engine.kernels.exact): with
--relax 0, one exact step instead of the cascade (exact_move; order then holds the ids that moved, in
the order the step moved them, and sponsor is -1 throughout: the step has no sponsors); with --relax N,
the cascade and relaxation, then the exact-limit pass. Fixed elements stay, and a grabbed element whose
target the limits cannot reach stops at the reachable position nearest it. OUT.npz then also holds
changed (ids the step or pass moved), residual (worst distance of a link from its box, in rest lengths)
and shortfall (how far the grabbed element stopped from its target). Without --exact the result is the
thesis cascade, unchanged. --stats prints how many links end outside their
limits, for this result and for a plain cascade in every order.

Every input is checked before anything runs; a bad one is a one-line error (exit 2) and nothing is
written. The result is written to a temporary file and renamed into place only when complete.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import NamedTuple

import numpy as np

from chainsim.game.common.outputs import check_output_file
from chainsim.systems.engine import argtypes
from chainsim.systems.engine.atomicfile import atomic_open
from chainsim.systems.engine.bodies.chainmail import ChainMailBody
from chainsim.systems.engine.chainmail_params import ORDER_CHOICES, ORDERS, check_material, order_code, order_name
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.kernels.chainmail import make_workspace, material_arrays
from chainsim.systems.engine.kernels.exact import ExactResult, exact_move, violations
from chainsim.systems.engine.kernels.graph import Graph, build_graph
from chainsim.systems.engine.meshimport import load_graph

NAME = "chainmail"
HELP = "move one element of a mesh with Generalised ChainMail and save the result (.npz)"


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP, description=HELP)
    p.add_argument(
        "mesh", metavar="MESH", help=".npz with positions/links[/fixed], or a mesh file (.obj .ply .stl .msh .vtu ...)"
    )
    p.add_argument("--grab", type=argtypes.element, required=True, metavar="I", help="id of the element to move")
    p.add_argument(
        "--to", type=argtypes.coordinate, nargs="+", required=True, metavar="X", help="target position: D coordinates"
    )
    p.add_argument(
        "--alpha-min", type=argtypes.real(0.0, 1.0), required=True, metavar="A", help="compression limit in [0, 1]"
    )
    p.add_argument("--alpha-max", type=argtypes.real(1.0), required=True, metavar="B", help="stretch limit >= 1")
    p.add_argument("--beta", type=argtypes.real(0.0), required=True, metavar="C", help="shear limit >= 0")
    p.add_argument(
        "--relax",
        type=argtypes.relax,
        default=0,
        metavar="N",
        help="relaxation sweeps after the cascade (default 0: raw cascade)",
    )
    p.add_argument(
        "--relax-step",
        type=argtypes.real(0.0, 1.0, low_open=True),
        default=1.0,
        metavar="S",
        help="relaxation step in (0, 1] (default 1)",
    )
    p.add_argument(
        "--order",
        choices=ORDER_CHOICES,
        default="breadth-first",
        help="waiting-list order (default breadth-first; fifo is the same order)",
    )
    p.add_argument(
        "--exact",
        action="store_true",
        help="afterwards put every link back inside its limits (a target out of reach is approached as near as "
        "the limits allow)",
    )
    p.add_argument(
        "--stats", action="store_true", help="print the links left outside their limits, for this and every order"
    )
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
    check_output_file(out, "--out")


class Move(NamedTuple):
    """One move's result: positions (N, D), order (moved ids), sponsor (N,), exact (ExactResult or None)."""

    positions: np.ndarray
    order: np.ndarray
    sponsor: np.ndarray
    exact: ExactResult | None


class Body(NamedTuple):
    """The arrays one mesh needs for moves (built once, reused for every order in --stats)."""

    rest: np.ndarray
    graph: Graph
    mat: tuple[np.ndarray, np.ndarray, np.ndarray]
    fixed: np.ndarray | None


def make_body(positions, links, fixed_ids, alpha_min, alpha_max, beta) -> Body:
    rest = np.array(positions, dtype=np.float64, copy=True, order="C")
    n = len(rest)
    graph = build_graph(n, links)
    fixed = None
    if len(fixed_ids):
        fixed = np.zeros(n, dtype=np.bool_)
        fixed[fixed_ids] = True
    return Body(rest, graph, material_arrays(graph.n_links, alpha_min, alpha_max, beta), fixed)


def move(body: Body, grab: int, target, relax_n=0, relax_step=1.0, order="breadth-first", exact=False) -> Move:
    """Cascade (then relaxation, then the exact pass) from the rest shape, through the engine's body; exact
    without relaxation is one exact step instead (no cascade: kernels.exact.exact_move)."""
    if exact and not relax_n:
        pos = body.rest.copy()
        target = np.asarray(target, dtype=np.float64).reshape(1, -1)
        changed, res = exact_move(
            body.rest, pos, body.graph, *body.mat, np.array([grab], dtype=np.int64), target, body.fixed,
            make_workspace(len(pos)), order=order_code(order), check=True,
        )  # fmt: skip
        changed = changed.astype(np.int64)  # a copy: the step's ids are a view into its workspace
        return Move(pos, changed, np.full(len(pos), -1, dtype=np.int64), res._replace(changed=changed))
    cm = ChainMailBody(
        body.rest,
        body.graph,
        *body.mat,
        relax=relax_n,
        relax_step=relax_step,
        order=order,
        exact=exact,
        fixed=body.fixed,
        dtype=body.rest.dtype,
    )
    target = np.asarray(target, dtype=np.float64).reshape(1, -1)
    cm.move([grab], target, hold=False)
    sponsor = np.full(cm.n, -1, dtype=np.int64)
    sponsor[cm.last_order] = cm.last_sponsor
    return Move(cm.positions, cm.last_order.astype(np.int64), sponsor, cm.last_exact if exact else None)


def write_result(out: Path, positions, order, sponsor, **extra) -> None:
    """Write OUT.npz atomically: a temporary file in the same folder, renamed when complete."""

    try:
        with atomic_open(out, "wb") as fh:
            np.savez(fh, positions=positions, order=order, sponsor=sponsor, **extra)
    except OSError as e:
        raise UserError(f"--out: cannot write {out} ({e.strerror or e})") from None


def stats_lines(body: Body, m: Move, args) -> list[str]:
    """The --stats report: this result's links outside their limits, then a plain cascade per order."""
    v = violations(body.rest, m.positions, body.graph, *body.mat)
    name = order_name(args.order)
    how = f"{name}{', relax ' + str(args.relax) if args.relax else ''}{', exact' if args.exact else ''}"
    lines = [
        f"result ({how}): {len(m.order)} moved, {v.outside} of {v.links} links outside their limits "
        f"({100 * v.share:.2f} %), worst {v.worst:.3g} rest lengths out"
    ]
    if m.exact is not None:
        e = m.exact
        lines.append(
            f"exact: {len(e.changed)} elements changed, worst residual {e.residual:.3g} rest lengths, "
            f"shortfall {e.shortfall:.6g} ({'target reached' if e.shortfall == 0 else 'target out of reach'})"
            + ("" if e.complete else "; stopped at the visit cap")
        )
    relax = f", relax {args.relax}" if args.relax else ""
    lines.append(f"plain cascade{relax}, by order:   moved   links outside   worst (rest lengths)")
    for order in ORDERS:
        p = move(body, args.grab, args.to, args.relax, args.relax_step, order)
        pv = violations(body.rest, p.positions, body.graph, *body.mat)
        lines.append(f"  {order:14s} {len(p.order):16d}   {100 * pv.share:10.2f} %   {pv.worst:12.3g}")
    return lines


def run(args) -> int:
    check_args(args)
    positions, links, fixed = load_graph(args.mesh, kind=args.kind)
    n, dim = positions.shape
    if not 0 <= args.grab < n:
        raise UserError(f"--grab: element id must be in 0..{n - 1}, got {args.grab}")
    if len(args.to) != dim:
        raise UserError(f"--to: the mesh is {dim}-D, so give {dim} coordinate(s); got {len(args.to)}")
    try:
        body = make_body(positions, links, fixed, args.alpha_min, args.alpha_max, args.beta)
        m = move(body, args.grab, args.to, args.relax, args.relax_step, args.order, args.exact)
    except ValueError as e:  # the kernels' own checks, if anything slipped past ours
        raise UserError(f"{args.mesh}: {e}") from None
    extra = {}
    if m.exact is not None:
        extra = {"changed": m.exact.changed, "residual": m.exact.residual, "shortfall": m.exact.shortfall}
    write_result(Path(args.out), m.positions, m.order, m.sponsor, **extra)
    if args.stats:
        print("\n".join(stats_lines(body, m, args)))
    short = f"; {m.exact.shortfall:.6g} short of the target" if m.exact is not None and m.exact.shortfall else ""
    print(f"moved {len(m.order)} of {n} elements{short}; wrote {args.out}", file=sys.stderr)
    return 0
