"""The ChainMail benchmark suite behind `chainsim bench chainmail` (see tools/bench_chainmail.py).

Parts:
  thesis   the experiment of thesis 6.2.1: square grids of 11, 25, 51 and 75 elements a side; rigid,
           medium and soft materials; Gibson's ChainMail (4.2) and Generalised ChainMail (5.2); the
           highest and lowest update rates, from a small move of the centre element (only its
           neighbourhood follows) to a large one (every element follows), beside Tables 6.2-6.4.
           The thesis measured browser frame rates (Java + VRML, AMD-K7); ours are cascade-only updates
           per second, so the ratio says how much faster the move itself now is, not the whole frame.
  worst    Fig. 6.4: the centre element of a rigid grid moved at a constant rate 20 times around a
           40 x 40 square path; every update moves the whole object.
  scaling  rigid full cascades on tetrahedral blocks and triangle sheets from 10^3 to 10^6 elements,
           with and without relaxation, in generated order, shuffled (random ids) and shuffled then
           reordered (reverse Cuthill-McKee, chainsim.systems.engine.reorder); plus a local grab on the largest mesh.
  drag     soft presets dragged 12 frames through ChainMailBody.move, float64 and float32, at 100k and
           1M elements, beside the lean cascade on the same frames (tools/bench/drag.py).
  threads  the level-parallel cascade against the serial one on the same drags, by size and thread count.
  exact    the pulls of tools/bench/exact_cases.py (the prp face pulled 8, 22 and 46 mm, rim fixed or
           not; the face filled with tetrahedra; a tet block) in every waiting-list order, and whole-body
           pulls of 1.7k-1M-element tet blocks (breadth-first): the links the plain cascade leaves outside
           their limits, and beside it the exact step's cost (kernels.exact.exact_move), residual and
           shortfall.
"""

from __future__ import annotations

import json
import math
import os
import platform
import statistics
import sys
import time
from functools import partial
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numba
import numpy as np

from chainsim.systems.engine import atomicfile, meshgen
from chainsim.systems.engine.chainmail_params import ORDERS, check_material, order_code, order_name
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.kernels.chainmail import cascade, make_workspace, material_arrays
from chainsim.systems.engine.kernels.exact import exact_limits, exact_move, violations
from chainsim.systems.engine.kernels.gibson import gibson_grid_move
from chainsim.systems.engine.kernels.graph import build_graph
from chainsim.systems.engine.kernels.lean import LeanWorkspace, lean_move
from chainsim.systems.engine.meshimport import load_graph
from chainsim.systems.engine.reorder import rcm_permutation
from chainsim.systems.tissue.deformation import relax_moved
from chainsim.tools.bench import drag, exact_cases
from chainsim.tools.bench.meshes import relabel, surface_sheet, tet_cube

# Tables 6.2-6.4 (frames/second): size -> (Gibson hi, lo, SurfaceChainMail hi, lo, Generalised hi, lo)
THESIS = {
    "rigid": {
        121: (90.9, 58.82, 90.9, 45.5, 90.9, 58.82),
        625: (37, 30.3, 37, 30.3, 45.5, 37),
        2601: (10.75, 10.36, 11.4, 10.6, 10.8, 10.1),
        5625: (5.2, 5.18, 5.2, 4.8, 5.7, 5.1),
    },
    "medium": {
        121: (90.9, 58.82, 90.9, 45.5, 90.9, 58.82),
        625: (45.45, 37.03, 45.45, 30.3, 90.9, 37),
        2601: (37.03, 12.04, 22.7, 13, 45.5, 10.1),
        5625: (22.73, 6.99, 20.4, 6.5, 22.7, 6.1),
    },
    "soft": {
        121: (90.9, 58.82, 90.9, 45.5, 90.9, 58.82),
        625: (90.9, 37.03, 90.9, 30.3, 90.9, 37),
        2601: (45.45, 12.04, 30.3, 13.4, 45.5, 10.1),
        5625: (26.31, 6.99, 22.7, 6.5, 22.7, 6.5),
    },
}
TABLE_OF = {"rigid": "6.2", "medium": "6.3", "soft": "6.4"}
# alpha_min, alpha_max as in 6.2.1 (after Gibson 1999); the thesis gives no shear value, these are ours
MATERIALS = {"rigid": (1.0, 1.0, 0.0), "medium": (0.8, 1.2, 0.1), "soft": (0.5, 2.5, 0.3)}
SIDES = (11, 25, 51, 75)
PARTS = ("thesis", "worst", "scaling", "exact", "drag", "threads")


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


class Times(list):
    """Wall-clock seconds per call; `.cpu` holds the process CPU seconds of the same calls.

    On a shared machine the wall clock also counts time the process waited for a core; CPU time counts
    only what it ran (kernels here are single-threaded, so the two agree on an idle machine).
    """

    cpu: list


def time_calls(fn, reset, repeat: int, warmup: int = 2) -> Times:
    """Seconds per call of fn(), reset() run untimed before each call."""
    for _ in range(warmup):
        reset()
        fn()
    out = Times()
    out.cpu = []
    for _ in range(repeat):
        reset()
        c0 = time.process_time()
        t0 = time.perf_counter()
        fn()
        t1 = time.perf_counter()
        out.cpu.append(time.process_time() - c0)
        out.append(t1 - t0)
    return out


def time_interleaved(fns, reset, repeat: int, warmup: int = 2) -> list[Times]:
    """Like time_calls for several functions, alternating them call by call, so a shared, noisy machine
    loads each the same way; one Times per function."""
    for _ in range(warmup):
        for fn in fns:
            reset()
            fn()
    out = [Times() for _ in fns]
    for t in out:
        t.cpu = []
    for _ in range(repeat):
        for fn, t in zip(fns, out):
            reset()
            c0 = time.process_time()
            t0 = time.perf_counter()
            fn()
            t1 = time.perf_counter()
            t.cpu.append(time.process_time() - c0)
            t.append(t1 - t0)
    return out


def cpu_ms(times: Times) -> float:
    return statistics.median(times.cpu) * 1e3


def median_ms(times: list[float]) -> float:
    return statistics.median(times) * 1e3


# -- the generalised kernel, set up once per mesh ----------------------------------------------------


class Body:
    """rest/pos/graph/materials/workspace of one mesh, for timing cascades (and the lean yardstick)."""

    def __init__(self, rest, links, amin, amax, beta, fixed=None):
        self.rest = np.ascontiguousarray(rest, dtype=np.float64)
        self.pos = self.rest.copy()
        self.graph = build_graph(len(rest), links)
        self.mat: tuple[np.ndarray, np.ndarray, np.ndarray] = material_arrays(self.graph.n_links, amin, amax, beta)
        # one material for every link (what the lean kernel takes), else None
        self.scalar: tuple[float, float, float] | None = (
            (float(amin), float(amax), float(beta)) if np.ndim(amin) == 0 else None
        )
        self.ws = make_workspace(len(rest))
        self.lean_ws = LeanWorkspace(len(rest))
        self.fixed = None if fixed is None or not np.any(fixed) else np.ascontiguousarray(fixed, dtype=np.bool_)
        self.moved = 0
        self.exact = None  # the last move's ExactResult
        self.touched = None  # id arrays moved since the last reset (None: unknown, reset everything)

    def reset(self) -> None:
        """Back to rest: only the elements the last move touched are copied back (as an interactive
        drag would leave the rest of the mesh, and its caches, alone)."""
        if self.touched is None or len(self.touched) > 2:  # unknown, or several moves since: everything
            np.copyto(self.pos, self.rest)
        else:
            for ids in self.touched:  # views of the last move's id lists, still valid before the next
                self.pos[ids] = self.rest[ids]
        self.touched = []

    def call(self, grab: int, target, **kw):
        """move() with its arguments made once (so a timing loop times the move, not array building)."""
        grabbed = np.array([grab], dtype=np.int64)
        target = np.ascontiguousarray(target, dtype=np.float64).reshape(1, -1)
        return partial(self.move, grabbed, target, **kw)

    def lean_call(self, grab: int, target):
        """The lean cascade (kernels.lean) for the same move: one material, no anchors, no cuts."""
        target = np.ascontiguousarray(target, dtype=np.float64).reshape(-1)
        return partial(self._lean, int(grab), target)

    def _lean(self, grab, target) -> None:
        assert self.scalar is not None  # lean_call is used on bodies of one material (MATERIALS)
        g = self.graph
        self.moved = lean_move(self.rest, self.pos, g.indptr, g.indices, grab, target, *self.scalar, self.lean_ws)
        self._touch(self.lean_ws.order[: self.moved])

    def _touch(self, ids) -> None:
        if self.touched is not None and len(self.touched) <= 2:
            self.touched.append(ids)

    def move(self, grab, target, order: int = 0, relax_n: int = 0, exact: bool = False, parallel: bool = False):
        grabbed = grab if isinstance(grab, np.ndarray) else np.array([grab], dtype=np.int64)
        if not isinstance(target, np.ndarray) or target.ndim != 2:
            target = np.asarray(target, dtype=np.float64).reshape(1, -1)
        if exact and not relax_n:  # the exact step replaces the cascade (kernels.exact.exact_move)
            changed, self.exact = exact_move(
                self.rest, self.pos, self.graph, *self.mat, grabbed, target, self.fixed, self.ws, order
            )
            self.moved = len(changed)
            self._touch(changed)
            return
        moved, _ = cascade(
            self.rest,
            self.pos,
            self.graph,
            *self.mat,
            grabbed,
            target,
            fixed=self.fixed,
            order=order,
            workspace=self.ws,
            copy=False,
            parallel=parallel,
        )
        self.moved = len(moved)
        self._touch(moved)
        if relax_n:
            pin = np.zeros(len(self.pos), dtype=np.bool_) if self.fixed is None else self.fixed.copy()
            pin[grabbed] = True
            relax_moved(self.rest, self.pos, self.graph, moved, relax_n, fixed=pin)
        if exact:
            self.exact = exact_limits(
                self.rest, self.pos, self.graph, *self.mat, moved, grabbed, target, self.fixed, self.ws
            )
            self._touch(self.exact.changed)

    def violations(self):
        return violations(self.rest, self.pos, self.graph, *self.mat)


# -- part a: thesis 6.2 ------------------------------------------------------------------------------


def thesis_part(quick: bool, repeat: int) -> list[dict]:

    rows = []
    for side in SIDES:
        rest, links = meshgen.grid((side, side))
        n = side * side
        c = side // 2 + side * (side // 2)
        reps = repeat or (15 if quick else (60 if n < 3000 else 30))
        for mname, (amin, amax, beta) in MATERIALS.items():
            body = Body(rest, links, amin, amax, beta)
            # small: only the neighbourhood follows; large: past every limit, the whole object follows
            small = max(1.5 * (amax - 1.0), 0.25)
            large = 2.0 * side * max(amax, 1.0)
            row = {"side": side, "elements": n, "material": mname}
            for label, disp in (("high", small), ("low", large)):
                target = rest[c] + np.array([disp, disp * 0.5])
                t, tl = time_interleaved([body.call(c, target), body.lean_call(c, target)], body.reset, reps)
                row[f"gen_{label}_ms"] = median_ms(t)
                row[f"gen_{label}_cpu_ms"] = cpu_ms(t)
                row[f"lean_{label}_ms"] = median_ms(tl)
                row[f"lean_{label}_cpu_ms"] = cpu_ms(tl)
                row[f"gen_{label}_moved"] = body.moved
                gpos = rest.copy()
                gib = partial(gibson_grid_move, gpos, (side, side), c, target, amin, amax, beta)
                t = time_calls(gib, partial(np.copyto, gpos, rest), reps)
                row[f"gib_{label}_ms"] = median_ms(t)
                row[f"gib_{label}_cpu_ms"] = cpu_ms(t)
                np.copyto(gpos, rest)
                row[f"gib_{label}_moved"] = int(gib())  # one more move from rest, for its count
            th = THESIS[mname][n]
            row["thesis"] = {
                "gibson_high": th[0],
                "gibson_low": th[1],
                "surface_high": th[2],
                "surface_low": th[3],
                "generalised_high": th[4],
                "generalised_low": th[5],
            }
            rows.append(row)
            _log(
                f"  thesis grid {side}x{side} {mname}: generalised {row['gen_high_ms']:.4f} / "
                f"{row['gen_low_ms']:.4f} ms"
            )
    return rows


def worst_part(quick: bool) -> list[dict]:
    """Fig. 6.4: rigid, centre element driven 20 times around a 40 x 40 square, one unit per update."""

    loops = 2 if quick else 20
    edge = np.linspace(-20.0, 20.0, 41)[:-1]
    square = np.concatenate(
        [
            np.stack([edge, np.full(40, -20.0)], 1),
            np.stack([np.full(40, 20.0), edge], 1),
            np.stack([-edge, np.full(40, 20.0)], 1),
            np.stack([np.full(40, -20.0), -edge], 1),
        ]
    )
    rows = []
    for side in SIDES:
        rest, links = meshgen.grid((side, side))
        c = side // 2 + side * (side // 2)
        path = rest[c] + np.tile(square, (loops, 1))
        body = Body(rest, links, *MATERIALS["rigid"])
        body.move(c, path[0])  # warm-up (compilation, caches)
        body.reset()
        c0, t0 = time.process_time(), time.perf_counter()
        for p in path:
            body.move(c, p)
        gen, gen_cpu = time.perf_counter() - t0, time.process_time() - c0
        gpos = rest.copy()
        gibson_grid_move(gpos, (side, side), c, path[0], 1.0, 1.0, 0.0)
        np.copyto(gpos, rest)
        c0, t0 = time.process_time(), time.perf_counter()
        for p in path:
            gibson_grid_move(gpos, (side, side), c, p, 1.0, 1.0, 0.0)
        gib, gib_cpu = time.perf_counter() - t0, time.process_time() - c0
        rows.append(
            {
                "side": side,
                "elements": side * side,
                "updates": len(path),
                "loops": loops,
                "generalised_total_s": gen,
                "generalised_ms_per_update": gen / len(path) * 1e3,
                "generalised_cpu_ms_per_update": gen_cpu / len(path) * 1e3,
                "gibson_total_s": gib,
                "gibson_ms_per_update": gib / len(path) * 1e3,
                "gibson_cpu_ms_per_update": gib_cpu / len(path) * 1e3,
                "moved_per_update": body.moved,
            }
        )
        _log(f"  worst case {side}x{side}: {gen / len(path) * 1e3:.4f} ms/update")
    return rows


# -- part b: scaling ---------------------------------------------------------------------------------


def _variants(rest, links, seed=1):
    """(name, rest, links, id map old->new) for ordered, shuffled and shuffled-then-reordered meshes."""

    n = len(rest)
    ident = np.arange(n)
    yield "ordered", rest, links, ident
    perm = np.random.default_rng(seed).permutation(n)
    srest, slinks, sinv = relabel(rest, links, perm)
    yield "shuffled", srest, slinks, sinv
    rperm = rcm_permutation(n, slinks)
    rrest, rlinks, rinv = relabel(srest, slinks, rperm)
    yield "shuffled+rcm", rrest, rlinks, rinv[sinv]


def scaling_part(quick: bool, repeat: int, max_elements: float) -> list[dict]:

    sizes = [s for s in (1e3, 1e4, 1e5, 1e6) if s <= max_elements * 1.01]
    rows = []
    for kind, make in (("tet volume", tet_cube), ("triangle sheet", surface_sheet)):
        for size in sizes:
            t_build = time.perf_counter()
            rest, _cells, links = make(int(size))
            n = len(rest)
            centre = int(np.argmin(np.sum((rest - rest.mean(axis=0)) ** 2, axis=1)))
            reps = repeat or (max(5, min(50, int(2e6 / n))) if not quick else max(3, min(20, int(5e5 / n))))
            _log(f"  {kind} n={n} links={len(links)} built in {time.perf_counter() - t_build:.1f}s, {reps} repeats")
            base = {}
            for vname, vrest, vlinks, idmap in _variants(rest, links):
                body = Body(vrest, vlinks, *MATERIALS["rigid"])
                g = int(idmap[centre])
                target = vrest[g] + 0.5
                row = {
                    "mesh": kind,
                    "elements": n,
                    "links": int(len(links)),
                    "links_per_element": 2 * len(links) / n,
                    "variant": vname,
                    "repeats": reps,
                }
                t, tl = time_interleaved([body.call(g, target), body.lean_call(g, target)], body.reset, reps)
                # after, not interleaved: idle worker threads that spin between parallel regions would
                # otherwise be timed as part of the serial kernels' runs
                tp = time_calls(body.call(g, target, parallel=True), body.reset, reps)
                row["rigid_ms"] = median_ms(t)
                row["rigid_cpu_ms"] = cpu_ms(t)
                row["rigid_min_ms"] = min(t) * 1e3  # least disturbed run, for loaded machines
                row["lean_ms"] = median_ms(tl)
                row["lean_ratio"] = median_ms(t) / median_ms(tl)
                row["lean_cpu_ms"] = cpu_ms(tl)
                row["lean_cpu_ratio"] = cpu_ms(t) / max(cpu_ms(tl), 1e-9)
                row["parallel_ms"] = median_ms(tp)
                row["threads"] = numba.get_num_threads()
                row["rigid_moved"] = body.moved
                if vname != "shuffled":
                    t = time_calls(body.call(g, target, relax_n=2), body.reset, max(3, reps // 2))
                    row["rigid_relax2_ms"] = median_ms(t)
                    row["rigid_relax2_cpu_ms"] = cpu_ms(t)
                # a local grab: medium material, one spacing of pull; a few hundred elements follow
                local = Body(vrest, vlinks, *MATERIALS["medium"])
                ltarget = vrest[g] + np.r_[0.0, 0.0, 1.0][: vrest.shape[1]]
                t = time_calls(local.call(g, ltarget), local.reset, max(reps, 20))
                row["local_ms"] = median_ms(t)
                row["local_cpu_ms"] = cpu_ms(t)
                row["local_moved"] = local.moved
                base[vname] = row["rigid_cpu_ms"]
                row["ratio_to_ordered"] = row["rigid_cpu_ms"] / base["ordered"]
                rows.append(row)
                _log(
                    f"    {vname:13s} rigid {row['rigid_ms']:.3f} ms (cpu {row['rigid_cpu_ms']:.3f}), lean "
                    f"{row['lean_ms']:.3f} ms ({row['lean_ratio']:.2f}x), level-parallel {row['parallel_ms']:.3f} ms "
                    f"({row['threads']} threads)  local {row['local_ms']:.4f} ms "
                    f"({row['local_moved']} moved)  ratio {row['ratio_to_ordered']:.2f}"
                )
                body = local = None  # free this variant's bodies before building the next
    return rows


# -- part: exact limits ------------------------------------------------------------------------------


def exact_part(quick: bool, repeat: int) -> list[dict]:
    """Per case, pull and order: the plain cascade (time, moved, links left outside their limits) and
    the cascade followed by the exact-limit pass (time, residual, shortfall)."""
    rows = []
    whole = exact_cases.whole_body_cases(1e5 if quick else 1e6)
    for case in exact_cases.cases(quick) + whole:
        big = case in whole
        reps = repeat or (3 if big and len(case.rest) > 1e5 else (7 if quick or big else 25))
        _log(f"  {case.name}: {len(case.rest)} elements, {len(case.links)} links")
        body = Body(case.rest, case.links, *exact_cases.MATERIAL, fixed=case.fixed)
        for mm in case.pulls:
            target = case.rest[case.grab] + mm * case.direction
            for name in ORDERS[:1] if big else ORDERS:  # whole body: breadth-first (the step is order-free)
                code = order_code(name)
                t = time_calls(body.call(case.grab, target, order=code), body.reset, reps)
                v = body.violations()
                row = {
                    "case": case.name,
                    "elements": len(case.rest),
                    "pull_mm": mm,
                    "order": name,
                    "plain_ms": median_ms(t),
                    "plain_cpu_ms": cpu_ms(t),
                    "moved": body.moved,
                    "outside_share": v.share,
                    "outside_worst": v.worst,
                }
                t = time_calls(body.call(case.grab, target, order=code, exact=True), body.reset, reps)
                e = body.exact
                after = body.violations()
                row |= {
                    "exact_ms": median_ms(t),
                    "exact_cpu_ms": cpu_ms(t),
                    "exact_ratio": cpu_ms(t) / max(row["plain_cpu_ms"], 1e-9),
                    "exact_changed": len(e.changed),
                    "exact_visits": e.visits,
                    "residual": max(e.residual, after.worst),
                    "exact_outside": after.outside,
                    "shortfall_mm": e.shortfall,
                }
                rows.append(row)
                _log(
                    f"    {mm:4.0f} mm {name:13s} plain {row['plain_ms']:.4f} ms, {100 * v.share:5.2f} % outside "
                    f"(worst {v.worst:.2f}); exact {row['exact_ms']:.4f} ms ({row['exact_ratio']:.1f}x), residual "
                    f"{row['residual']:.1e}, short {e.shortfall:.2f} mm"
                )
    return rows


# -- report ------------------------------------------------------------------------------------------


def _cpu(row: dict, key: str, digits: int = 3) -> str:
    """A CPU-time figure of a row, or '-' for results written before it was recorded."""
    return f"{row[key]:.{digits}f}" if key in row else "-"


def _cpu_ratio(row: dict, num: str, den: str) -> str:
    if f"{den}_cpu_ms" not in row:
        return "-"
    return f"{row[f'{num}_cpu_ms'] / max(row[f'{den}_cpu_ms'], 1e-9):.2f}"


def _fmt_rate(ms: float) -> str:
    return f"{1000.0 / ms:,.0f}" if ms > 0 else "inf"


def markdown(results: dict) -> str:
    out = [
        "# Generalised ChainMail benchmark\n",
        f"{results['machine']} - numpy {results['numpy']}, numba {results['numba']}; medians of repeated runs "
        "after warm-up.\n",
    ]
    if results.get("thesis"):
        out += _thesis_section(results["thesis"])
    if results.get("worst"):
        out += _worst_section(results["worst"])
    if results.get("scaling"):
        out += _scaling_section(results["scaling"])
    if results.get("exact"):
        out += _exact_section(results["exact"])
    out += drag.markdown(results)
    return "\n".join(out)


def _thesis_section(rows: list[dict]) -> list[str]:
    """Thesis 6.2, Tables 6.2-6.4: our update rates on square grids beside the published ones."""
    out = []
    out.append("## Thesis 6.2: update rates on square grids (updates/s; thesis: browser frames/s)\n")
    out.append(
        "Ours: cascade-only updates per second (1000 / median ms). Thesis: Java + VRML frame rates on an "
        "AMD-K7, Tables 6.2-6.4. 'high' = small move of the centre element, 'low' = a move that every "
        "element follows. Moved = elements moved by our generalised run. Low vs lean: its time over the lean "
        "cascade's (chainsim.systems.engine.kernels.lean) for the same move, timed alternately in the same run "
        "(wall "
        "clock; CPU time in brackets).\n"
    )
    out.append(
        "Rates from wall-clock medians; in brackets, from CPU-time medians (what the process itself "
        "ran; differs only on a busy machine).\n"
    )
    out.append(
        "| table | material | grid | ours gen. high | thesis gen. high | ratio | ours gen. low | thesis gen. low "
        "| ratio | moved low | low vs lean | ours Gibson high | ours Gibson low | thesis Gibson high / low |"
    )
    out.append("|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    for r in rows:
        th = r["thesis"]
        hi, lo = 1000 / r["gen_high_ms"], 1000 / r["gen_low_ms"]
        chi, clo = 1000 / max(r["gen_high_cpu_ms"], 1e-6), 1000 / max(r["gen_low_cpu_ms"], 1e-6)
        out.append(
            f"| {TABLE_OF[r['material']]} | {r['material']} | {r['side']}x{r['side']} | {hi:,.0f} ({chi:,.0f}) | "
            f"{th['generalised_high']:g} | {hi / th['generalised_high']:,.0f}x "
            f"({chi / th['generalised_high']:,.0f}x) | "
            f"{lo:,.0f} ({clo:,.0f}) | {th['generalised_low']:g} | {lo / th['generalised_low']:,.0f}x "
            f"({clo / th['generalised_low']:,.0f}x) | {r['gen_low_moved']} | "
            f"{r['gen_low_ms'] / r['lean_low_ms']:.2f} ({_cpu_ratio(r, 'gen_low', 'lean_low')}) | "
            f"{_fmt_rate(r['gib_high_ms'])} | "
            f"{_fmt_rate(r['gib_low_ms'])} | "
            f"{th['gibson_high']:g} / {th['gibson_low']:g} |"
        )
    out.append("")
    return out


def _worst_section(rows: list[dict]) -> list[str]:
    """Fig. 6.4's worst case: a rigid grid whose centre element goes round a square."""
    out = []
    out.append("## Fig. 6.4 worst case: rigid grid, centre element 20 times around a 40 x 40 square\n")
    out.append(
        "| grid | elements | updates | generalised ms/update (cpu) | generalised total s "
        "| Gibson ms/update (cpu) | Gibson total s |"
    )
    out.append("|---|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        out.append(
            f"| {r['side']}x{r['side']} | {r['elements']} | {r['updates']} | "
            f"{r['generalised_ms_per_update']:.4f} ({r['generalised_cpu_ms_per_update']:.4f}) | "
            f"{r['generalised_total_s']:.3f} | {r['gibson_ms_per_update']:.4f} "
            f"({r['gibson_cpu_ms_per_update']:.4f}) | {r['gibson_total_s']:.3f} |"
        )
    out.append("")
    return out


def _scaling_section(rows: list[dict]) -> list[str]:
    """The rigid full cascade, a local grab and relaxation on meshes of growing size and each order."""
    out = []
    out.append("## Scaling: rigid full cascade (every element moves), local grab, relaxation\n")
    out.append(
        "Wall-clock medians, CPU-time medians in brackets; the ratio to the generated order uses CPU time. "
        "Lean: the lean cascade (chainsim.systems.engine.kernels.lean: one material, no anchors, no cuts), timed "
        "alternately with the rigid cascade in the same run; vs lean = rigid / lean (wall clock, CPU time in "
        "brackets: on a busy machine the longer call is preempted more often). Level-parallel: the "
        "breadth-first cascade wave by wave on numba's threads (same result), timed after them.\n"
    )
    out.append(
        "| mesh | elements | links/elem | order | rigid ms | lean ms | vs lean | level-parallel ms (threads) "
        "| with relax(2) ms | ratio to ordered | local grab ms | local moved |"
    )
    out.append("|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        rel = f"{r['rigid_relax2_ms']:.3f} ({r['rigid_relax2_cpu_ms']:.3f})" if "rigid_relax2_ms" in r else "-"
        out.append(
            f"| {r['mesh']} | {r['elements']:,} | {r['links_per_element']:.1f} | {r['variant']} | "
            f"{r['rigid_ms']:.3f} ({r['rigid_cpu_ms']:.3f}) | {r['lean_ms']:.3f} ({_cpu(r, 'lean_cpu_ms')}) | "
            f"{r['lean_ratio']:.2f} ({_cpu(r, 'lean_cpu_ratio', 2)}) | "
            f"{r['parallel_ms']:.3f} ({r['threads']}) | {rel} | {r['ratio_to_ordered']:.2f} | "
            f"{r['local_ms']:.4f} ({r['local_cpu_ms']:.4f}) | {r['local_moved']} |"
        )
    out.append("")
    return out


def _exact_section(rows: list[dict]) -> list[str]:
    """Exact limits: the links a plain cascade leaves outside their box, and the exact step's cost."""
    out = []
    out.append("## Exact limits: links the cascade leaves outside, and the exact step\n")
    out.append(
        "Material 0.8 / 1.2, beta 0.1 (tools/bench/exact_cases.py). Plain: one cascade from rest; outside: "
        "share of all links outside their box after it, and the worst distance from a box in rest lengths. "
        "Exact: one exact step from rest instead (exact_move, no cascade). Times are CPU-time medians (the "
        "wall clock is in results.json); ratio: exact over plain; residual: the worst distance from a box after "
        "it (rest lengths); short: how far the grabbed element stopped from its target (0: reached).\n"
    )
    out.append(
        "| case | pull mm | order | moved | plain ms | outside | worst | exact ms | ratio | residual | short mm |"
    )
    out.append("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        out.append(
            f"| {r['case']} | {r['pull_mm']:g} | {r['order']} | {r['moved']} | {r['plain_cpu_ms']:.3f} | "
            f"{100 * r['outside_share']:.2f} % | {r['outside_worst']:.2f} | {r['exact_cpu_ms']:.3f} | "
            f"{r['exact_ratio']:.1f}x | {r['residual']:.1e} | {r['shortfall_mm']:.2f} |"
        )
    out.append("")
    return out


def plot(results: dict, path: Path) -> None:

    matplotlib.use("Agg")

    fig, axes = plt.subplots(1, 3, figsize=(17, 5))
    if results.get("thesis"):
        ax = axes[0]
        for mname, mk in (("rigid", "o"), ("medium", "s"), ("soft", "^")):
            rs = [r for r in results["thesis"] if r["material"] == mname]
            n = [r["elements"] for r in rs]
            ax.plot(n, [1000 / r["gen_low_ms"] for r in rs], mk + "-", label=f"ours, {mname}, low")
            ax.plot(
                n, [r["thesis"]["generalised_low"] for r in rs], mk + "--", color="grey", label=f"thesis, {mname}, low"
            )
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("elements")
        ax.set_ylabel("updates (frames) per second")
        ax.set_title("Thesis 6.2 grids: lowest rates")
        ax.legend(fontsize=7)
    if results.get("worst"):
        ax = axes[1]
        rs = results["worst"]
        ax.plot(
            [r["elements"] for r in rs], [r["generalised_cpu_ms_per_update"] for r in rs], "o-", label="Generalised"
        )
        ax.plot([r["elements"] for r in rs], [r["gibson_cpu_ms_per_update"] for r in rs], "s-", label="Gibson")
        ax.set_xlabel("elements")
        ax.set_ylabel("CPU ms per update")
        ax.set_title("Fig. 6.4 worst case (rigid, 40x40 square path)")
        ax.legend()
    if results.get("scaling"):
        ax = axes[2]
        for kind, ls in (("tet volume", "-"), ("triangle sheet", ":")):
            for variant, mk in (("ordered", "o"), ("shuffled", "x"), ("shuffled+rcm", "s")):
                rs = [r for r in results["scaling"] if r["mesh"] == kind and r["variant"] == variant]
                if rs:
                    ax.plot(
                        [r["elements"] for r in rs],
                        [r["rigid_cpu_ms"] for r in rs],
                        mk + ls,
                        label=f"{kind}, {variant}",
                    )
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("elements")
        ax.set_ylabel("rigid full cascade, CPU ms (median)")
        ax.set_title("Scaling")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_suite(args) -> int:

    parts = {p.strip() for p in args.parts.split(",") if p.strip()}
    if args.exact:
        parts.add("exact")
    unknown = parts - set(PARTS)
    if unknown:
        raise UserError(f"--parts: unknown part(s) {', '.join(sorted(unknown))}; expected {', '.join(PARTS)}")
    if args.repeat < 0:
        raise UserError(f"--repeat: must be >= 0, got {args.repeat}")
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"--out {out}: cannot create folder ({e.strerror})") from None
    max_el = args.max_elements or (1e5 if args.quick else 1e6)
    load = f", load average {os.getloadavg()[0]:.1f} at start" if hasattr(os, "getloadavg") else ""
    results = {
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, {platform.system()}{load}",
        "numpy": np.__version__,
        "numba": numba.__version__,
        "quick": bool(args.quick),
    }
    t0 = time.perf_counter()
    if "thesis" in parts:
        _log("thesis 6.2 grids ...")
        results["thesis"] = thesis_part(args.quick, args.repeat)
    if "worst" in parts:
        _log("worst case (Fig. 6.4) ...")
        results["worst"] = worst_part(args.quick)
    if "scaling" in parts:
        _log("scaling ...")
        results["scaling"] = scaling_part(args.quick, args.repeat, max_el)
    if "exact" in parts:
        _log("exact limits ...")
        results["exact"] = exact_part(args.quick, args.repeat)
    if "drag" in parts:
        _log("drags ...")
        results["drag"] = drag.drag_part(args.quick, args.repeat, max_el)
    if "threads" in parts:
        _log("level-parallel against serial, by size and thread count ...")
        results["threads"] = drag.threads_part(args.quick, args.repeat, max_el)
    results["wall_s"] = time.perf_counter() - t0
    md = markdown(results)
    atomicfile.write_text(out / "results.json", json.dumps(results, indent=1))
    atomicfile.write_text(out / "results.md", md)
    plot(results, out / "results.png")
    print(md)
    print(f"wrote {out / 'results.md'}, results.json, results.png", file=sys.stderr)
    return 0


# -- part c: one mesh --------------------------------------------------------------------------------


def run_mesh(args) -> int:
    pos, links, fixed_ids = _mesh_for(args)
    n, dim = pos.shape
    fixed = np.zeros(n, dtype=np.bool_)
    fixed[fixed_ids] = True
    body = Body(pos, links, args.alpha_min, args.alpha_max, args.beta, fixed=fixed)
    order = order_code(args.order)
    reps = args.repeat or 20
    times, lean_t = time_interleaved(
        [body.call(args.grab, args.to, order=order, relax_n=args.relax), body.lean_call(args.grab, args.to)],
        body.reset,
        reps,
    )
    result = {
        "mesh": str(args.mesh),
        "elements": n,
        "links": int(len(links)),
        "dim": dim,
        "fixed": int(len(fixed_ids)),
        "median_ms": median_ms(times),
        "min_ms": min(times) * 1e3,
        "max_ms": max(times) * 1e3,
        "repeats": reps,
        "lean_median_ms": median_ms(lean_t),
        "lean_ratio": median_ms(times) / max(median_ms(lean_t), 1e-12),
        "cpu_median_ms": cpu_ms(times),
        "lean_cpu_median_ms": cpu_ms(lean_t),
        "lean_cpu_ratio": cpu_ms(times) / max(cpu_ms(lean_t), 1e-12),
        "elements_moved": body.moved,
        "order": order_name(args.order),
        "relax": args.relax,
    }
    if args.exact:
        t = time_calls(body.call(args.grab, args.to, order=order, relax_n=args.relax, exact=True), body.reset, reps)
        e = body.exact
        result["exact"] = {
            "median_ms": median_ms(t),
            "ratio": median_ms(t) / max(result["median_ms"], 1e-12),
            "residual": e.residual,
            "shortfall": e.shortfall,
            "changed": int(len(e.changed)),
            "visits": e.visits,
            "complete": e.complete,
        }
    # the links each order's plain cascade leaves outside their limits (off the sponsor chains)
    result["violations"] = {}
    for name in ORDERS:
        body.reset()
        body.move(args.grab, args.to, order=order_code(name), relax_n=args.relax)
        v = body.violations()
        result["violations"][name] = {"moved": body.moved, "outside_share": v.share, "worst": v.worst}
    if args.json:
        print(json.dumps(result))
    else:
        _print_mesh_result(result, reps)
    return 0


def _mesh_for(args):
    """(positions, links, fixed ids) of --mesh, once the material, --grab, --to and --repeat are checked."""
    check_material(args.alpha_min, args.alpha_max, args.beta)
    if args.grab is None or args.to is None:
        raise UserError("--mesh needs --grab I and --to X [Y [Z]]")
    if not all(math.isfinite(v) for v in args.to):
        raise UserError("--to: coordinates must be finite")
    if args.repeat < 0:
        raise UserError(f"--repeat: must be >= 0, got {args.repeat}")
    pos, links, fixed_ids = load_graph(args.mesh)
    n, dim = pos.shape
    if not 0 <= args.grab < n:
        raise UserError(f"--grab: element id must be in 0..{n - 1}, got {args.grab}")
    if len(args.to) != dim:
        raise UserError(f"--to: the mesh is {dim}-D, so give {dim} coordinate(s); got {len(args.to)}")
    return pos, links, fixed_ids


def _print_mesh_result(result: dict, reps: int) -> None:
    r = result
    print(
        f"{r['mesh']}: {r['elements']} elements, {r['links']} links; one {r['order']} cascade moving "
        f"{r['elements_moved']} elements: median {r['median_ms']:.4f} ms over {reps} runs; the lean "
        f"cascade {result['lean_median_ms']:.4f} ms (ratio {result['lean_ratio']:.2f}; CPU time "
        f"{result['cpu_median_ms']:.4f} against {result['lean_cpu_median_ms']:.4f} ms, {result['lean_cpu_ratio']:.2f})"
    )
    if "exact" in result:
        e = result["exact"]
        print(
            f"with {'the exact-limit pass' if result['relax'] else 'the exact step'}: median {e['median_ms']:.4f} ms "
            f"({e['ratio']:.2f}x the plain cascade), "
            f"worst residual {e['residual']:.2g} rest lengths, shortfall {e['shortfall']:.6g}"
        )
    print("links left outside their limits by a plain cascade:")
    for name, v in result["violations"].items():
        print(
            f"  {name:14s} {v['moved']:8d} moved  {100 * v['outside_share']:6.2f} % outside, "
            f"worst {v['worst']:.3g} rest lengths"
        )
