"""ChainMail as a model in the study: cascade (thesis 5.2.3, 3-D box of 5.2.6) followed by 0..k
relaxation sweeps (5.2.5), run through the engine's own kernels in systems/kernels.

The grabbed patch is moved to its target from the rest shape in one cascade: the worst case for a
given displacement, since every affected element moves in that single update.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from chainsim.systems.engine.bodies.chainmail import ChainMailBody
from chainsim.systems.engine.kernels.chainmail import make_workspace, material_arrays
from chainsim.systems.engine.kernels.graph import build_graph


@dataclass
class ChainMailParams:
    alpha_min: float
    alpha_max: float
    beta: float
    relax_iterations: int = 0


class ChainMailModel:
    def __init__(self, pos, links, fixed_ids=None, order: str = "fifo"):

        self.rest = np.ascontiguousarray(pos, dtype=np.float64)
        self.n = len(self.rest)
        self.graph = build_graph(self.n, np.asarray(links, dtype=np.int64))
        self.ws = make_workspace(self.n)
        self.fixed = None
        if fixed_ids is not None and len(fixed_ids):
            self.fixed = np.zeros(self.n, np.bool_)
            self.fixed[np.asarray(fixed_ids, dtype=np.int64)] = True
        self.order_name = order
        self._mat_key: tuple[float, float, float] | None = None

    def _materials(self, p: ChainMailParams):

        key = (p.alpha_min, p.alpha_max, p.beta)
        if key != self._mat_key:
            self._mat = material_arrays(self.graph.n_links, *key)
            self._mat_key = key
        return self._mat

    def solve(self, grabbed, disp, params: ChainMailParams):
        """Displacement field (N, 3) after grabbing `grabbed` and moving it by `disp` (K, 3).

        Returns (u, info) with the cascade and relaxation wall times and the number moved.
        """

        amin, amax, beta = self._materials(params)
        grabbed = np.ascontiguousarray(grabbed, dtype=np.int64)
        targets = np.ascontiguousarray(self.rest[grabbed] + np.asarray(disp).reshape(-1, 3))
        body = ChainMailBody(
            self.rest,
            self.graph,
            amin,
            amax,
            beta,
            relax=int(params.relax_iterations),
            order=self.order_name,
            fixed=self.fixed,
        )
        body.workspace = self.ws
        t0 = time.thread_time()
        body.move(grabbed, targets, hold=False)
        t2 = time.thread_time()
        moved = len(body.last_order)
        t1 = t0 + body.stats.extra.get("t_cascade", t2 - t0)
        pos = body.positions
        u = pos - self.rest
        if not np.all(np.isfinite(u)):
            raise FloatingPointError("ChainMail produced non-finite positions")
        return u, {"t_cascade": t1 - t0, "t_relax": t2 - t1, "t_total": t2 - t0, "moved": moved}
