"""Plain-Python references for the kernel tests, written from the thesis rules (5.2.2-5.2.6), not
from the kernels: a literal waiting list served one entry at a time, adjacency rebuilt from the link list,
plus random test meshes of every kind the kernels must handle."""

from __future__ import annotations

import heapq
import math
from collections import deque

import numpy as np

from chainsim.systems.engine import meshgen


def adjacency(n, links, alive):
    """Neighbour lists in increasing link id: [(neighbour, link id), ...] per element, live links only."""
    adj = [[] for _ in range(n)]
    for lid, (u, v) in enumerate(np.asarray(links).tolist()):
        if alive[lid]:
            adj[u].append((v, lid))
            adj[v].append((u, lid))
    return adj


def box(rest, pos, e, s, a, amin, amax, beta):
    d = float(rest[e, a]) - float(rest[s, a])
    ad = abs(d)
    o = 0.0
    for b in range(rest.shape[1]):
        if b != a:
            o += abs(float(rest[e, b]) - float(rest[s, b]))
    base = float(pos[s, a])
    if d >= 0.0:
        return base + (amin * ad - beta * o), base + (amax * ad + beta * o)
    return base - (amax * ad + beta * o), base - (amin * ad - beta * o)


def try_move(rest, pos, e, s, amin, amax, beta):
    moved = False
    for a in range(pos.shape[1]):
        lo, hi = box(rest, pos, e, s, a, amin, amax, beta)
        x = pos[e, a]
        if float(x) < lo:
            pos[e, a] = lo
        elif float(x) > hi:
            pos[e, a] = hi
        if pos[e, a] != x:
            moved = True
    return moved


def violation(rest, pos, e, s, amin, amax, beta):
    v = 0.0
    for a in range(pos.shape[1]):
        lo, hi = box(rest, pos, e, s, a, amin, amax, beta)
        x = float(pos[e, a])
        if x < lo:
            v += (lo - x) * (lo - x)
        elif x > hi:
            v += (x - hi) * (x - hi)
    return math.sqrt(v)


def ref_cascade(rest, pos, links, alive, amin, amax, beta, grabbed, targets, fixed=None, order=0, depth=2):
    """Returns (new positions, order list, sponsor list).

    order: 0 breadth-first, 1 balanced, 2 Schill, 3 depth-first (5.2.3's "front of the waiting list")."""
    pos = pos.copy()
    n = len(pos)
    fixed = np.zeros(n, bool) if fixed is None else fixed
    adj = adjacency(n, links, alive)
    moved = set()
    out, spons = [], []
    for g, t in zip(np.asarray(grabbed).tolist(), targets):
        if fixed[g]:
            continue
        pos[g] = t
        moved.add(g)
        out.append(g)
        spons.append(-1)

    def candidates(s):
        return [(e, lid) for e, lid in adj[s] if e not in moved and not fixed[e]]

    def accept(e, s, lid):
        if e in moved or not try_move(rest, pos, e, s, amin[lid], amax[lid], beta[lid]):
            return False
        moved.add(e)
        out.append(e)
        spons.append(s)
        return True

    if order == 0:
        waiting = deque((e, s, lid) for s in list(out) for e, lid in candidates(s))
        while waiting:
            e, s, lid = waiting.popleft()
            if accept(e, s, lid):
                waiting.extend((f, e, l2) for f, l2 in candidates(e))
    elif order == 3:
        waiting = deque((e, s, lid) for s in list(out) for e, lid in candidates(s))
        while waiting:
            e, s, lid = waiting.popleft()
            if accept(e, s, lid):
                # the new block goes to the front, in its listed order
                waiting.extendleft(reversed([(f, e, l2) for f, l2 in candidates(e)]))
    elif order == 1:
        branches = [deque([(e, s, lid, 1)]) for s in list(out) for e, lid in candidates(s)]
        limit = depth
        while branches:
            for br in branches:
                while br and br[0][3] <= limit:
                    e, s, lid, dep = br.popleft()
                    if accept(e, s, lid):
                        br.extend((f, e, l2, dep + 1) for f, l2 in candidates(e))
            branches = [br for br in branches if br]
            limit += depth
    else:
        heap, seq = [], 0

        def push(s):
            nonlocal seq
            for e, lid in candidates(s):
                v = violation(rest, pos, e, s, amin[lid], amax[lid], beta[lid])
                if v > 0.0:
                    heapq.heappush(heap, (-v, seq, e, s, lid))
                    seq += 1

        for s in list(out):
            push(s)
        while heap:
            _, _, e, s, lid = heapq.heappop(heap)
            if accept(e, s, lid):
                push(e)
    return pos, np.array(out, dtype=np.int64), np.array(spons, dtype=np.int64)


# ------------------------------------------------------------------------------------------------
# random meshes

MESH_KINDS = ("curve", "planar", "surface", "volume", "random")


def random_mesh(kind: str, dim: int, rng: np.random.Generator, size: int = 6):
    """(rest positions (N, D) float64, links (M, 2)) of the given kind, jittered so it is irregular."""
    if kind == "curve":
        n = 3 + 3 * size
        steps = rng.normal(size=(n, dim))
        steps[:, 0] = np.abs(steps[:, 0]) + 0.2  # wander but mostly advance
        pos = np.cumsum(steps, axis=0)
        links = meshgen.chain(n, dim=dim)[1]
    elif kind == "planar":
        pos, _, links = meshgen.triangulated_grid(size, size - 1, dim=2)
        pos = pos + rng.uniform(-0.3, 0.3, pos.shape)
    elif kind == "surface":
        pos, _, links = meshgen.triangulated_grid(size, size, dim=3)
        pos[:, 2] = np.sin(pos[:, 0]) * np.cos(0.7 * pos[:, 1])
        pos = pos + rng.uniform(-0.2, 0.2, pos.shape)
    elif kind == "volume":
        k = max(2, size // 2)
        pos, _, links = meshgen.tet_grid(k + 1, k, k)
        pos = pos + rng.uniform(-0.25, 0.25, pos.shape)
    else:
        n = 4 + 4 * size
        pos, links = meshgen.random_graph(n, 2 * n, dim, rng, scale=float(size))
    return np.ascontiguousarray(pos, dtype=np.float64), links
