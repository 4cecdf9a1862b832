"""A soft body as a scene holds it: the body of its current model and the state that outlives a model switch.

A scene's soft body runs one model at a time (ChainMail, XPBD, projective, hybrid, SurfaceChainMail: its
`model_body`) and may switch between them from the same rest shape. What drawing, picking, tools and the
world digest read of it lives here, once: positions, the rest shape, the link graph and which links are
alive, the elements held and fixed, the per-link ChainMail limits, `version` (bumped by every change a
reader must see) and the ids moved since the renderer last took them (`take_dirty`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from chainsim.systems.engine.bodies.base import Body
from chainsim.systems.engine.bodies.chainmail import ChainMailBody
from chainsim.systems.engine.kernels.graph import Graph
from chainsim.systems.engine.meshes import MeshData


def _ids(values: Any = ()) -> np.ndarray:
    return np.asarray(values, dtype=np.int64).reshape(-1)


class SoftBody:
    """The runtime state of one soft body (see the module docstring); `model_body` does the solving."""

    def __init__(
        self,
        rest: np.ndarray,
        mesh: MeshData,
        links: np.ndarray,
        fixed: np.ndarray,
        limits: tuple[np.ndarray, ...],
        *,
        relax_iterations: int,
        exact: bool,
        material: Any = None,
    ) -> None:
        n = len(rest)
        self.rest = rest  # (N, 3) in the body's precision, the mesh's vertex order
        self.mesh = mesh  # the pack's mesh: a model switch builds the next body from it
        self.links = links  # the ChainMail links (M, 2): the mesh's own, or its cells' edges
        self.fixed = fixed  # bool (N,): elements that never move
        # per-link (amin, amax, beta) of `links` a new ChainMail body is built with, from `material`
        self.base_limits = limits
        self.material = material  # what the limits were resolved from (the tissue's material and regions)
        # the material's relaxation and exact-limit pass: a ChainMail body takes them at each move
        self.relax_iterations = int(relax_iterations)
        self.exact = bool(exact)
        self.model_body: Any = None  # the body solving now (ChainMailBody, XPBDBody, ...): set by `adopt`
        self.model_used = "chainmail"
        self.model_reason = ""
        self.version = 0
        self.held = _ids()  # the elements a tool holds (fixed ones too: the model body skips those)
        self.held_targets = np.zeros((0, 3))
        self.transient = _ids()  # held for one step only (a grab without hold)
        # Young's modulus (Pa) and Poisson's ratio per tetrahedron when a feature gives the body several
        # materials (empty: the model's E and nu for the whole body); kept across model switches
        self.element_E = np.zeros(0)
        self.element_nu = np.zeros(0)
        self._dirty = _ids()
        self._dirty_mask = np.zeros(n, dtype=np.bool_)

    # -- what readers see ------------------------------------------------------------------------
    @property
    def n(self) -> int:
        return len(self.rest)

    @property
    def positions(self) -> np.ndarray:
        """(N, 3) current positions in the body's own frame: the model body's array itself."""
        return self.model_body.positions

    @property
    def graph(self) -> Graph:
        """The links a blade can cut, with their alive flags."""
        return self.model_body.graph

    @property
    def alive(self) -> np.ndarray:
        """bool per link of `graph`: False once cut."""
        return self.model_body.graph.alive

    @property
    def limits(self) -> tuple[np.ndarray, ...]:
        """Per-link (amin, amax, beta): a ChainMail body's own (on its graph's links, added ones too),
        else those of `links` the next ChainMail body is built with."""
        if isinstance(self.model_body, ChainMailBody):
            return self.model_body.amin, self.model_body.amax, self.model_body.beta
        return self.base_limits

    @property
    def dynamic(self) -> bool:
        """A model that integrates every step (ChainMail moves only when grabbed)."""
        return self.model_body is not None and self.model_body.model != "chainmail"

    @property
    def last_order(self) -> np.ndarray:
        """The elements the last ChainMail move visited, in order (empty for other models)."""
        return getattr(self.model_body, "last_order", _ids())

    @property
    def last_sponsor(self) -> np.ndarray:
        return getattr(self.model_body, "last_sponsor", _ids())

    @property
    def last_shortfall(self) -> float:
        """How far the last exact ChainMail move fell short of its target (0 for other models)."""
        return float(getattr(self.model_body, "last_shortfall", 0.0))

    # -- what changed since a reader last looked ---------------------------------------------------
    @property
    def dirty(self) -> np.ndarray:
        """The ids moved since the renderer last took them (each once, in the order they moved)."""
        return self._dirty

    def mark_dirty(self, ids: np.ndarray) -> None:
        """Add `ids` to `dirty` (cost follows len(ids), not N)."""
        ids = np.asarray(ids, dtype=np.int64)
        new = np.unique(ids[~self._dirty_mask[ids]])
        if len(new):
            self._dirty_mask[new] = True
            self._dirty = np.concatenate([self._dirty, new])

    def take_dirty(self) -> np.ndarray:
        """`dirty`, emptied: the renderer uploads these."""
        out = self._dirty
        if len(out):
            self._dirty_mask[out] = False
            self._dirty = _ids()
        return out

    def changed(self, ids: np.ndarray | None = None) -> None:
        """A change readers must see: `ids` moved (None: the whole body), the version moves on."""
        self.mark_dirty(np.arange(self.n) if ids is None else ids)
        self.version += 1

    # -- holding -----------------------------------------------------------------------------------
    def adopt(self, model_body: Body, model: str, reason: str) -> None:
        """Run `model_body` from now on (built from `rest`); nothing is held."""
        self.model_body = model_body
        self.model_used = model
        self.model_reason = reason
        self.held_targets = np.zeros((0, 3))
        # a ChainMail body keeps its own anchors (a move holds what it moved); the others are held here
        self.held = model_body.held if isinstance(model_body, ChainMailBody) else _ids()
