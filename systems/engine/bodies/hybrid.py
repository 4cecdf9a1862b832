"""Tissue that settles in a few frames: projective dynamics (the corotational energy of
chainsim.systems.engine.bodies.projective) solved by a two-level iteration, with sleeping far from the tool.

Why two levels: projective dynamics' local-global iteration contracts by about 1 - 2 mu / (2 mu + 3
lambda) per iteration (0.976 at nu = 0.45), because its global matrix is a Laplacian per axis and knows
nothing of the coupling of the axes through the volume term; a grab from rest then takes tens of
frames with a few CG steps each. Linear elasticity's stiffness K (the energy's Hessian at rest) does know
it, and the smooth part of the answer, the part that is slow for the Laplacian, is what a coarse grid
represents well. So each frame:

1. one local step gives the forces f = -grad W at the current shape (rotations warm-started), the
   energy and the smallest det F;
2. coarse correction: the displacement in the span of a trilinear coarse grid (spacing `coarse` times
   the mean edge) that minimises the linearised energy, P (P^T K P)^-1 P^T f (Galerkin, factorised once
   per set of held and awake nodes, a few thousand unknowns);
3. smoothing: a few CG steps on K itself (block-Jacobi) for the forces left after step 2 (updated
   linearly through K), which fixes what the coarse grid cannot represent. Projective dynamics' own
   matrix stiffens every direction by the volume weight, so its steps shrink as nu nears 0.5;
4. the step is taken as far as a line search allows: the energy must fall (Armijo), no element may fall
   below det F 0.1, and the curvature along the step (from the slopes at both ends) shortens a step that
   overshoots the energy's minimum on that line or lengthens one that falls well short. Under a still
   target the iterations are preconditioned nonlinear conjugate gradients (Polak-Ribiere, restarted
   when the formula gives a negative share or when the targets move): the two-level step of 2-3 is the
   preconditioner, and each new step carries on the last direction by the share that keeps the two
   K-conjugate, to first order.

Held for seconds (chapter 6's tables stop at the first frames; a tool holds tissue for seconds): with
steps that only lower the energy the body cannot alternate between two shapes, as the plain two-level
iteration did under a still tool (a 0.65 mm flicker at 30 Hz on the 10k-node study block), nor overshoot
a far pull threefold. Once the step, the motion still to come and the forces are all negligible, the
body is at rest and a frame costs nothing until the targets move. The corotational energy charges a
squeezed element through the sum of its stretches, not its volume, so a far shear could fold elements
flat for little energy: below det F 0.5 a compression barrier (kernels.twolevel.volume_barrier) adds a
cost that grows without bound as the element flattens, as the neo-Hookean -ln J does. A frame's move of
the grabbed nodes is shortened where it would squeeze an element past that (by at most a tenth a frame),
so a far pull is reached over a few frames, like a nonlinear FEM's load steps; a pull that no shape can
follow (through the fixed base) stops short, and `notice` says so in one line.

The coarse step is a Newton step with the rest Hessian, right only while the rotations follow the
shape: with one rotation refinement per local step they lag a sudden grab and the iteration diverged
on a 10k-node block (lifted 10 %); two or three per step converge. The rotations of all elements are
refined together in one pass per refinement, with no branch and no trigonometry, so the pass runs in
SIMD lanes (kernels.twolevel.local_forces).

A new grab target (`start = "linear"`, the default): before the frame's nonlinear step the jump of the
grabbed nodes is spread through the body by the rest stiffness (forces -K jump on the solved nodes, one
coarse solve), so the local step sees a body already near its new shape rather than
one ring of elements stretched by the whole jump; that ring is what made the first frame of a grab
poor. With `start = "chainmail"` the start is one ChainMail cascade (thesis 5.2.3) from the current
shape instead, the idea of starting physics from the cascade's one-pass spread (measured in `chainsim
bench models`: its cone is further from tissue than the linear spread); `start = "none"` starts from
the current shape. `coarse = 0` leaves out the coarse step (then this is projective dynamics with CG
steps).

The iteration's fixed point is f = 0, the projective energy's equilibrium, so its answer is the static
projective solution (statics: no inertia). After the last release, with the fixed nodes at rest, that
answer is the rest shape itself, and the body goes there in the frame of the release (no creep back over
many frames). A piece that nothing holds (cut free) keeps its place: statics gives it none.

Sleeping (`sleep` > 0): only awake nodes are solved; sleepers are held where they are. A grab wakes the
held nodes and `wake_rings` rings around them; a node wakes its sleeping neighbours (with `wake_rings`
rings) once the largest drift within two rings inside it, since it last did, passes `sleep` times the
displacement scale, so the awake region follows the disturbance outwards, under a slow drag too (a
per-frame test never saw a hand's small steps); with nothing grabbed and every change below the
threshold, the body falls asleep. The cost of a frame is then that of the awake region, not of the body.
The sleepers are not frozen, though: each frame they are placed on the body's linear far field under the
force the tool applies (far_field.py), and a node's drift is counted from where that field put it, so
the awake region grows where the far field is wrong, near the tool. Held sleepers left 27 % of the
displacement field out on a 111k-node slab; on the far field the figure is 3 %.
"""

from __future__ import annotations

import math
import time

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.sparse.linalg import splu

from chainsim.systems.engine import meshgen
from chainsim.systems.engine.bodies.base import Cells, StepStats
from chainsim.systems.engine.bodies.chainmail import ChainMailBody
from chainsim.systems.engine.bodies.far_field import FarField
from chainsim.systems.engine.bodies.projective import ProjectiveBody
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.kernels.projective import pcg3, spmv3
from chainsim.systems.engine.kernels.twolevel import (
    assemble_tets,
    block_pcg,
    bspmv3,
    det_at,
    follow_far,
    local_forces,
    min_det,
    min_det_below,
    ring_max,
    tet_components,
    tet_pattern,
    tet_stiffness,
    trilinear_weights,
    wake_front,
)
from chainsim.systems.engine.model_params import HYBRID_STARTS, defaults

STARTS = HYBRID_STARTS
#: the body's defaults, from the one declaration of its parameters
_D = defaults("hybrid")
#: set-ups kept for held/awake sets seen before (a release and a re-grab of the same patch cost nothing)
CACHE = 4


#: the smallest volume ratio det F a step may leave an element at (or where it already was, if lower)
J_FLOOR = 0.1
#: below this volume ratio an element meets the compression barrier (kernels.twolevel.volume_barrier)
J_BARRIER = 0.5
#: a frame's start may squeeze the most squeezed element to this share of its ratio, never below J_START
#: or J_FLOOR (see _start)
J_START = 0.5
START_SQUEEZE = 0.9
#: halvings of a frame's start (the grabbed nodes' move) and of a two-level step before giving up
START_HALVINGS = 10
LINE_HALVINGS = 5
#: the energy must fall by this share of what the step's slope promises (Armijo's condition)
ARMIJO = 1e-4
#: a still body is at rest once its step, and what is estimated still to go, are below this share of
#: the displacement scale (a tenth of the 0.1 % of the pull a held shape may change by in a frame)
REST_TOLERANCE = 1e-4
#: ... and the largest force left is below this share of the largest since the targets last moved
REST_FORCE = 1e-3
#: rings inside the front whose largest drift a front node reports (see _sleep_or_wake)
DRIFT_RINGS = 2
MARGIN_RINGS = 12  # rings of elements assembled beyond the awake region (sleeping bodies)
#: once this share of the body's free nodes is awake, all of it wakes (see _sleep_or_wake)
WAKE_ALL = 0.8
#: `coarse = "auto"`: the coarse grid's spacing in mean edges, and from this Poisson ratio on the finer
#: one. A trilinear coarse field hardly keeps volume, so near incompressibility the coarse step does
#: little and the smoothing carries the solve: at nu 0.499 the 10,625-node block took 13 frames to
#: within 10 % of its answer at 3 edges, 10 at 2. Below 0.497 the finer grid only makes a moving frame
#: dearer (a 4 mm drag at nu 0.45: 34 ms against 22 ms a frame on one thread); chainsim bench models
#: --parts stiffness
COARSE = 3.0
COARSE_STIFF = 2.0
NU_STIFF = 0.497
#: the sleepers' far-field grid spacing, in spacings of the coarse step's grid (far_field.py)
FAR_SPACING = 1.0
FAR_STILL = 0.01
FAR_EVERY = 4


def coarse_spacing(coarse: float | str, nu: float) -> float:
    """The coarse grid's spacing in mean edges for the `coarse` setting (COARSE, or COARSE_STIFF from
    NU_STIFF, when "auto"), or UserError."""
    if coarse == "auto":
        return COARSE_STIFF if nu >= NU_STIFF else COARSE
    if isinstance(coarse, str) or not (coarse == 0.0 or 1.5 <= coarse <= 16.0):
        raise UserError(f"coarse: expected auto, 0 (off) or a grid spacing of 1.5..16 mean edges, got {coarse!r}")
    return float(coarse)


def first_share(far: np.ndarray, moved: np.ndarray) -> float:
    """The share of a grab's first far field to take: the body's linear response to the tool's force
    cannot carry the grabbed nodes further than the tool has moved them, so the far field's displacement
    of them (`far`) is scaled to fit their own (`moved`) in least squares, at most whole. On the 111k-node
    slab of `chainsim bench sleeping` it takes 0.6 (first frame 44 % of the field from the whole body,
    70 % whole); on the 80 mm slab of tests/engine/test_hybrid_long.py 1.0 (42 %, 52 % at a fixed half)."""
    uu = float(np.sum(far * far))
    return min(1.0, max(0.0, float(np.sum(far * moved)) / uu)) if uu > 0.0 else 0.0


class HybridBody(ProjectiveBody):
    """Static projective dynamics on tetrahedra, solved by coarse correction plus CG smoothing."""

    model = "hybrid"

    def __init__(
        self,
        rest: ArrayLike,
        tets: Cells | None,
        *,
        E: float = _D["E"],
        nu: float = _D["nu"],
        density: float = _D["density"],
        iterations: int = _D["iterations"],
        cg_iterations: int = _D["cg_iterations"],
        rotation_iterations: int = _D["rotation_iterations"],
        coarse: float | str = _D["coarse"],
        start: str = _D["start"],
        sleep: float = _D["sleep"],
        wake_rings: int = _D["wake_rings"],
        unit: float = _D["unit"],
        fixed: ArrayLike | None = None,
        alpha_min: ArrayLike = _D["alpha_min"],
        alpha_max: ArrayLike = _D["alpha_max"],
        beta: ArrayLike = _D["beta"],
    ) -> None:
        if tets is None or len(tets) == 0:
            raise UserError("a hybrid body needs tetrahedra (surfaces: use surface, projective or xpbd)")
        super().__init__(
            rest,
            tets,
            E=E,
            nu=nu,
            density=density,
            iterations=iterations,
            dynamic=False,
            unit=unit,
            solver="cg",
            cg_iterations=cg_iterations,
            rotation_iterations=rotation_iterations,
            fixed=fixed,
        )
        self.notice = ""  # CG is this body's own choice, not a switch from what was asked
        self._coarse_setting = coarse
        coarse = coarse_spacing(coarse, nu)
        if start not in STARTS:
            raise UserError(f"start: expected one of {', '.join(STARTS)}, got {start!r}")
        if not (math.isfinite(sleep) and 0.0 <= sleep < 1.0):
            raise UserError(f"sleep: expected a threshold in [0, 1) of the displacement scale, got {sleep}")
        if not (1 <= int(wake_rings) <= 1000):
            raise UserError(f"wake_rings: expected 1..1000, got {wake_rings}")
        self.coarse, self.start, self.sleep, self.wake_rings = float(coarse), start, float(sleep), int(wake_rings)
        self._released = False
        self._at_rest = True  # at the rest shape with nothing held: a step has nothing to do
        self._init_iteration()
        self._rest_si = rest_si = self.rest * self.unit
        links = meshgen.links_from_cells(self.tets)
        self.edge = float(np.mean(np.linalg.norm(rest_si[links[:, 0]] - rest_si[links[:, 1]], axis=1)))
        T = len(self.tets)
        self.K_e = tet_stiffness(self.D, self.vol, np.full(T, self.mu), np.full(T, self.lam))
        self._coarse_grid()
        self._chain = None
        if start == "chainmail":
            self._chain = ChainMailBody(self.rest, self.graph, alpha_min, alpha_max, beta, fixed=self.fixed)
        self.awake = np.ones(self.n, dtype=np.bool_) if not self.sleep else np.zeros(self.n, dtype=np.bool_)
        self._setups: dict = {}
        self._built = 0  # set-ups made (each a slice of the matrices and a coarse factorisation)
        self._matrices: tuple | None = None
        self._floating_cache: tuple | None = None
        self._synced: dict | None = None  # the set-up whose frame last wrote every position
        self._other_disp = 0.0
        self._far: FarField | None = self._build_far()
        self._setup: dict | None = None  # the solve's set-up for the current held and awake set
        # (set-up, stats) of a frame that changed nothing: the next one under the same targets is skipped
        self._quiet: tuple | None = None
        self._last_targets: np.ndarray | None = None
        self._sleep_scale = 0.0
        self._prev_last = 0.0
        # where each node was when it last woke its neighbours (sleeping bodies; see _sleep_or_wake)
        self._anchor = self.rest * self.unit

    def _build_far(self) -> FarField | None:
        """Sleepers follow the body's linear far field under the tool's force (far_field.py); its operator
        is built with the body, so that the first grab does not wait for it."""
        self._far_u = np.zeros((self.n, 3))  # the far field where it last placed the sleepers
        self._far_moved = False
        self._far_wait = 0  # frames under a still tool since the far field was last looked at
        self._g_rhs: np.ndarray | None = None  # scratch for the grabbed nodes' forces
        self._far_Y: np.ndarray | None = None
        if not (self.sleep and self.coarse):
            return None
        far = FarField(self._rest_si, self.tets, self.D, self.K_e, FAR_SPACING * self.coarse * self.edge)
        far.operators(self.active, self.fixed)
        return far

    def _init_iteration(self) -> None:
        # the last evaluation (set-up, energy, smallest det F, forces on its solved nodes), valid while x
        # is where it was evaluated: a still frame starts from it, with no local step of its own
        self._cache: tuple | None = None
        self._converged = False  # at rest under the current targets: frames cost nothing until they move
        self._prev_step = 0.0
        self._short_frames = 0
        # (set-up, last direction, its two-level step z, the forces z was made for): see _directions
        self._conjugate: tuple | None = None
        self._z: np.ndarray | None = None
        self._grab_key = b""
        self._f_peak = 0.0  # the largest force on a solved node since the targets last moved

    def _coarse_grid(self) -> None:
        """Each node's coarse-grid nodes and trilinear weights, on a grid of `coarse` mean edges."""
        if self.coarse:
            rest_si, h = self._rest_si, self.coarse * self.edge
            lo = rest_si.min(axis=0)
            dims = np.maximum(np.ceil((rest_si.max(axis=0) - lo) / h).astype(np.int64) + 1, 2)
            self._cids, self._cw = trilinear_weights(rest_si, lo, h, dims)

    def set_materials(self, E: ArrayLike, nu: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Per-tetrahedron E and nu (see ProjectiveBody.set_materials): the rest stiffness too, and every
        set-up assembled from the old one is dropped. With `coarse = "auto"` the grid follows the most
        nearly incompressible tetrahedron."""
        mu, lam = super().set_materials(E, nu)
        if self._coarse_setting == "auto":
            spacing = coarse_spacing("auto", float(np.max(np.asarray(nu, dtype=np.float64))))
            if spacing != self.coarse:
                self.coarse = spacing
                self._coarse_grid()
        self.K_e = tet_stiffness(self.D, self.vol, mu, lam)
        if self._far is not None:
            self._far = self._build_far()
        self._setups.clear()
        self._setup = self._matrices = self._synced = self._quiet = None
        self._cache, self._converged = None, False
        return mu, lam

    # -- set-up per held and awake set ----------------------------------------------------------
    def _placed(self) -> None:
        self._cache, self._converged = None, False  # set from outside: the last evaluation is stale
        # placed at its rest shape (as a tissue component hands a new body its positions) it is still at rest
        self._at_rest = not len(self.grab_ids) and np.array_equal(self._positions, self.rest)

    def _grab_changed(self) -> None:
        key = self.grab_ids.tobytes()
        if key != self._grab_key:  # other nodes held: not at rest (new targets are _solve's to see)
            self._converged, self._grab_key = False, key
        self._released = len(self.grab_ids) == 0
        if len(self.grab_ids):
            self._at_rest = False
        if self.sleep and len(self.grab_ids):
            self._wake_around(self.grab_ids)
        self._setup = None

    def _wake_around(self, ids: np.ndarray) -> None:
        change = np.zeros(self.n)
        before = self.awake.copy()
        self.awake[ids] = True
        change[ids] = 1.0
        wake_front(self.graph.indptr, self.graph.indices, self.awake, change, 0.5, self.wake_rings)
        new = self.awake & ~before
        self._anchor[new] = self.x[new]

    def _floating(self, held: np.ndarray) -> np.ndarray:
        """Nodes of pieces (connected through live elements) that nothing holds: a piece cut free, or a
        body let go with no fixed node. Statics gives such a piece no unique place (it may move rigidly
        at no cost, so its matrices are singular): it keeps where it is."""
        key = (held.tobytes(), self.active.tobytes())
        if self._floating_cache is not None and self._floating_cache[0] == key:
            return self._floating_cache[1]  # a drag keeps its held set: the pieces are those of last frame
        label = tet_components(self.n, self.tets, self.active)
        anchored = np.zeros(self.n, dtype=np.bool_)
        anchored[label[held]] = True
        self._floating_cache = (key, ~anchored[label])
        return self._floating_cache[1]

    def _assembled(self, touch: np.ndarray) -> tuple[sp.csr_matrix, sp.csr_matrix]:
        """Projective dynamics' global matrix L (n x n, one per axis) and the rest stiffness K (3n x 3n),
        assembled from the live elements around the awake region with a margin, so the rows of every
        solved node are whole. Assembled again only when elements are cut or the awake region outgrows
        the margin: a spreading disturbance costs an assembly every few wakes, and a body that sleeps
        never assembles the elements far from the tool."""
        key = self.active.tobytes()
        m = self._matrices
        if m is not None and m[0] == key and not np.any(touch & ~m[3]):
            return m[1], m[2]
        if self.sleep:
            near = self.awake.copy()  # the awake region grown by MARGIN_RINGS rings: the wake front's own rings
            wake_front(self.graph.indptr, self.graph.indices, near, np.ones(self.n), 0.5, MARGIN_RINGS)
            elems = self.active & near[self.tets].any(axis=1)
        else:
            elems = self.active.copy()
        ids = np.flatnonzero(elems)
        indptr, indices = tet_pattern(self.n, self.tets, ids)
        l_data, k_data = assemble_tets(indptr, indices, self.tets, ids, self.D, self.w_arap + self.w_vol, self.K_e)
        L = sp.csr_matrix((l_data, indices, indptr), shape=(self.n, self.n))
        K = sp.bsr_matrix((k_data, indices, indptr), shape=(3 * self.n, 3 * self.n)).tocsr()
        self._matrices = (key, L, K, elems)
        return L, K

    def _prepare_hybrid(self) -> dict:
        held = self.fixed.copy()
        held[self.grab_ids] = True
        # whether a held node is awake does not change the solve: keyed on it, a fixed node the front
        # reached would cost a new set-up (a factorisation) for the same nodes solved
        key = (held.tobytes(), (self.awake & ~held).tobytes(), self.active.tobytes())
        hit = self._setups.get(key)
        if hit is not None:
            return hit
        t0 = time.perf_counter()
        held |= self._floating(held)
        solve = ~held & self.awake
        free = np.flatnonzero(solve)
        # elements with a node to solve for: the only ones whose forces matter this frame
        touch = self.active & solve[self.tets].any(axis=1)
        # the matrices of the solved nodes are cut from the whole body's (assembled once per set of live
        # elements), so a region that wakes costs a slice and a coarse factorisation, not an assembly
        L, K = self._assembled(touch)
        nf = len(free)
        L_rows = L[free]
        L_ff = L_rows[:, free].tocsr()
        L_fo = L_rows.multiply(~solve[None, :]).tocsr()  # columns of the nodes held or asleep
        diag = L_ff.diagonal()
        if nf and np.any(diag <= 0.0):  # a node with no live element keeps its place
            L_ff = L_ff + sp.diags(np.where(diag <= 0.0, 1.0, 0.0))
            diag = L_ff.diagonal()
        s = {
            "free": free,
            "touch": touch,
            "elems": np.flatnonzero(touch),
            "L_ff": _csr(L_ff),
            "L_fo": _csr(L_fo),
            "inv_diag": 1.0 / diag if nf else np.zeros(0),
            "scratch": [np.zeros((nf, 3)) for _ in range(5)],
            "coarse": None,
        }
        if self.coarse and nf:
            # K on the solved dofs (3 i + axis)
            dofs = (3 * free[:, None] + np.arange(3)).ravel()
            K_rows = K[dofs]
            K_ff = K_rows[:, dofs].tocsr()
            # the smoother's matrix: K on the solved nodes as 3 x 3 blocks, with its diagonal blocks inverted
            Kb = K_ff.tobsr(blocksize=(3, 3))
            Kb.sort_indices()
            blocks = np.ascontiguousarray(Kb.data)
            bptr, bidx = Kb.indptr.astype(np.int64), Kb.indices.astype(np.int64)
            rows = np.repeat(np.arange(nf), np.diff(bptr))
            diag_blocks = np.zeros((nf, 3, 3))
            on = bidx == rows
            diag_blocks[rows[on]] = blocks[on]
            bad = np.abs(np.linalg.det(diag_blocks)) <= 1e-300
            diag_blocks[bad] = np.eye(3)
            s["K_ff"] = (bptr, bidx, blocks, np.linalg.inv(diag_blocks))
            s["coarse"] = _coarse_operators(K_ff, self._cids[free], self._cw[free])
            # K from the held dofs into the solved ones: the linear response to a move of the grabbed nodes
            s["K_fh"] = K_rows.multiply(np.repeat(~solve, 3)[None, :]).tocsr()
        if self._far is not None and len(self.grab_ids):
            # what the tool's force on the grabbed nodes needs: their elements and their rows of L
            grabbed = np.zeros(self.n, dtype=np.bool_)
            grabbed[self.grab_ids] = True
            s["g_nodes"] = np.flatnonzero(grabbed)
            s["g_elems"] = np.flatnonzero(self.active & grabbed[self.tets].any(axis=1))
            s["L_g"] = L[s["g_nodes"]].tocsr()
            s["sleeping"] = ~held & ~solve & ~self._floating(held)
        s["seconds"] = time.perf_counter() - t0
        if len(self._setups) >= CACHE:
            self._setups.pop(next(iter(self._setups)))
        self._setups[key] = s
        self._built += 1
        return s

    # -- a frame ----------------------------------------------------------------------------------
    def _solve(self, dt: float) -> StepStats:
        t0 = time.perf_counter()
        x = self.x
        targets = self.grab_targets * self.unit
        spread = self._chainmail_start(x, targets)
        still = self._last_targets is not None and np.array_equal(self._last_targets, targets)
        self._last_targets = targets.copy()
        settled = False
        if self._released:
            self._released = False
            self._at_rest = settled = self._settle_at_rest()
        if self._at_rest and not len(self.grab_ids):
            self._kept = not settled  # at rest since before this frame: nothing written
            return StepStats(0, 0.0, 0, time.perf_counter() - t0, {"setup_s": 0.0, "awake": 0, "solved": 0})
        quiet, self._quiet = self._quiet, None
        if quiet is not None and still and quiet[0] is self._setup and self._converged:
            # the last frame changed nothing under these same targets, and nothing touched the body since
            # (a grab, a release, a cut or new positions drop the set-up or the convergence): this frame
            # would change nothing either (a needle resting in converged tissue, frame after frame)
            self._quiet, self._kept = quiet, True
            return StepStats(0, 0.0, 0, time.perf_counter() - t0, dict(quiet[1]))
        if self._setup is None:
            self._setup = self._prepare_hybrid()
        s = self._setup
        before = (self._short_frames, self._prev_last, self.notice, self._sleep_scale)
        # nodes neither solved nor grabbed (fixed, asleep, floating) keep their place while the set-up
        # holds, so their largest displacement and their positions need no pass over the whole body
        partial = self._chain is None and s is self._synced
        if not partial:
            other = np.ones(self.n, dtype=np.bool_)
            other[s["free"]] = False
            other[self.grab_ids] = False
            d_other = np.abs(x[other] - self._rest_si[other])
            self._other_disp = float(d_other.max()) if d_other.size else 0.0
        free = s["free"]
        jump = targets - x[self.grab_ids]
        # the grabbed nodes' jump and its linear spread, shortened where it would turn elements inside out
        went = max(self._start(s, jump, x), spread)
        short = float(np.max(np.abs(targets - x[self.grab_ids]), initial=0.0))
        moving = np.concatenate([free, self.grab_ids])
        disp = max(self._other_disp, float(np.max(np.abs(x[moving] - self._rest_si[moving]), initial=0.0)))
        scale = max(disp, 1e-12 * self._scale)
        if went > 0.0 or (not still and not short):
            self._converged, self._conjugate, self._f_peak = False, None, 0.0
        elif short > 0.0:
            # held short and waiting (no share of the move keeps every element whole), the targets still
            # or not: nothing moved, and the body's answer depends on where the grabbed nodes are, not on
            # where they are asked to go. It settles there, and once it has, such frames cost no iteration
            # (a needle pressing on for seconds where the tissue cannot follow: 15 ms a frame before)
            self._conjugate = None
        done, last = 0, 0.0
        self._far_moved = False
        if len(free) and not self._converged:
            done, last, _ = self._iterate(s, x, scale)
            self._far_wait = 0 if not still else self._far_wait + 1
            if not still or self._converged or self._far_wait % FAR_EVERY == 0:
                # under a still tool the sleepers move once the awake region is at rest under them, or every
                # FAR_EVERY frames while it settles: each move then starts from nearly the awake region's
                # own answer (an outer iteration), and the body comes to rest once the far field stays
                self._follow_far(s, x, scale)
        self._say_short(short, scale)
        if self.sleep:
            self._sleep_or_wake(s, x, scale, last)
        self._write_positions(s, x, moving, partial)
        extra = {
            "setup_s": s["seconds"],
            "setups_built": self._built,
            "awake": int(self.awake.sum()),
            "solved": len(free),
            "min_j": self._cache[2] if self._cache is not None else math.nan,
            "converged": self._converged,
        }
        if self.notice:
            extra["notice"] = self.notice
        if still and partial and not went and not done and self._converged and self._setup is s:
            # nothing moved, nothing woke or slept, and the frame's own counters were already where it left
            # them: the next frame under the same targets repeats this one exactly
            if before == (self._short_frames, self._prev_last, self.notice, self._sleep_scale):
                self._quiet = (s, extra)
        return StepStats(done, last / scale if scale > 0 else 0.0, 0, time.perf_counter() - t0, extra)

    def _write_positions(self, s: dict, x: np.ndarray, moving: np.ndarray, partial: bool) -> None:
        if partial and not self._far_moved:
            self._positions[moving] = x[moving] / self.unit
        else:
            np.divide(x, self.unit, out=self._positions)
            # sleepers the far field moved: the next frame looks at the whole body again
            self._synced = None if self._far_moved else s

    def _follow_far(self, s: dict, x: np.ndarray, scale: float) -> None:
        """Place the sleepers on the body's far field under the force the tool now applies (far_field.py).
        A node's drift is then counted from where the far field put it, so the awake region grows where
        the far field is wrong (near the tool), not wherever the pull reaches."""
        if self._far is None or not s.get("sleeping", np.zeros(0, np.bool_)).any():
            return
        fl = self._floating_cache
        if fl is not None and fl[1].any():
            return  # a piece cut free has no linear answer (it may move rigidly): its sleepers keep still
        self._far.operators(self.active, self.fixed)
        g = s["g_nodes"]
        if self._g_rhs is None:
            self._g_rhs = np.zeros_like(x)
        rhs = self._g_rhs
        self._local_step(x, s["g_elems"], rhs)
        load = -(rhs[g] - s["L_g"] @ x)  # the tool holds the grabbed nodes against their elastic forces
        Y = self._far.response(g, load)
        if self._far_Y is None or self._far_Y.shape != Y.shape:
            # a new grab: the force is read from an awake region the sleepers still hold at rest, which
            # overstates it the more, the larger the body is beside that region
            Y = Y * first_share(self._far.at(g, Y), x[g] - self._rest_si[g])
        elif float(np.linalg.norm(Y - self._far_Y)) <= FAR_STILL * float(np.linalg.norm(Y)):
            return  # the sleepers are where the far field wants them, to FAR_STILL: the body may come to rest
        self._far_Y = Y
        moved = np.empty_like(x)
        far = self._far
        top = follow_far(far.cmap, far.weights, Y, self._rest_si, x, self._anchor, self._far_u, s["sleeping"], moved)
        if not top > 0.0:
            return
        self._far_moved = True  # the positions of the sleepers need writing
        if top > REST_TOLERANCE * scale:
            self._converged = False
        c = self._cache
        if c is not None and c[0] is s and "K_fh" in s:
            # the solved nodes' forces after the sleepers' move, to first order (as _start does)
            self._cache = (s, math.nan, c[2], c[3] - (s["K_fh"] @ moved.ravel()).reshape(-1, 3))
        else:
            self._cache = None

    def _chainmail_start(self, x: np.ndarray, targets: np.ndarray) -> float:
        """`start = "chainmail"`: a new target is spread through the body by one cascade, the solve refines.
        Returns 1.0 when it moved the body, else 0.0."""
        if self._chain is None or not len(self.grab_ids):
            return 0.0
        if self._last_targets is None or not np.array_equal(self._last_targets, targets):
            self._chain.positions[:] = x / self.unit
            self._chain.held = np.zeros(0, dtype=np.int64)
            self._chain.move(self.grab_ids, self.grab_targets)
            x[:] = self._chain.positions * self.unit
            self._cache = None
            return 1.0
        return 0.0

    def _start(self, s: dict, jump: np.ndarray, x: np.ndarray) -> float:
        """Move the grabbed nodes by `jump` towards their targets and, with `start = "linear"`, spread the
        jump through the body by the linear response on the coarse grid (forces -K_fh jump, one coarse
        solve), so the first local step sees a body already near the new shape, not one ring of elements
        stretched by the whole jump. Only the coarse step: what it leaves is the nonlinear step's to smooth
        (smoothing here too took a third more time a moving frame for the same frames to settle).

        The move is halved until no element it touches falls below J_FLOOR of its rest volume (or below
        where it already was): a far jump in one frame (a 12 mm shear of a 6 mm patch) otherwise folds the
        ring of elements around the grabbed nodes over, and an energy that does not forbid inversion keeps
        them folded. The grabbed nodes then reach their targets over the next frames, as the body makes
        room. Returns the share of the jump taken (0 when nothing moved)."""
        if not (len(self.grab_ids) and np.any(jump)):
            return 0.0
        free, g = s["free"], self.grab_ids
        lin = None
        if self.start == "linear" and s["coarse"] is not None and len(free):
            key = g.tobytes()
            if s.get("K_fg_key") != key:  # only the grabbed nodes' columns of K_fh act on a jump
                s["K_fg"] = s["K_fh"][:, (3 * g[:, None] + np.arange(3)).ravel()].tocsr()
                s["K_fg_key"] = key
            _, P, factor = s["coarse"]
            y = factor.solve(_spmv3(P[1], -(s["K_fg"] @ jump.ravel()).reshape(-1, 3)).ravel())
            lin = _spmv3(P[0], y.reshape(-1, 3))
        xg, xf = x[g].copy(), x[free].copy()
        # a frame's move may squeeze the most squeezed element by a tenth more, never below J_FLOOR: the
        # iterations between moves let the body make room, as the load steps of a nonlinear FEM do
        floor = -math.inf
        if len(s["elems"]):
            c = self._cache  # the last evaluation's smallest ratio is the one here, when it is of this x
            before = c[2] if c is not None and c[0] is s else min_det(x, self.tets, self.D, s["elems"])
            floor = max(J_FLOOR, START_SQUEEZE * min(J_START, before))
        alpha, min_j = 1.0, math.inf
        for _ in range(START_HALVINGS + 1):
            x[g] = xg + alpha * jump
            if lin is not None:
                x[free] = xf + alpha * lin
            min_j = self._start_ratio(s, x, floor) if len(s["elems"]) else math.inf
            if min_j >= floor:
                break
            alpha *= 0.5
        else:
            alpha = 0.0  # no share of the move keeps every element whole: the grabbed nodes wait
            x[g], x[free] = xg, xf
        if alpha == 1.0:
            x[g] = xg + jump  # exactly on target, with no round-off of xg + jump - xg
        c = self._cache
        if lin is not None and alpha > 0.0 and c is not None and c[0] is s:
            # the forces after the move, to first order: the last frame's less K times the move (the
            # coarse part through K P y). A moving tool then costs one local step a frame, as a still
            # one does, not two; the step's trial point is evaluated exactly, and its energy is unknown
            # here (nan: _iterate tests the step by its curvature and det F, not by the energy)
            moved = _bspmv3(s["coarse"][0], y.reshape(-1, 3)) + (s["K_fg"] @ jump.ravel()).reshape(-1, 3)
            self._cache = (s, math.nan, min_j, c[3] - alpha * moved)
        else:
            self._cache = None
        return alpha

    def _start_ratio(self, s: dict, x: np.ndarray, floor: float) -> float:
        """The smallest det F among the frame's elements at x, as far as the start's test needs it: the
        element that fell below `floor` last time is looked at first, and while it is still below, its
        own ratio is returned (below `floor` as the smallest is, and the start only compares it with
        `floor`). A pull held short of its target tries eleven ever shorter moves every frame, each
        failing on the same squeezed element; a whole pass each cost as much as the local step's
        gradients. det_at computes the element's ratio as min_det does, to the bit."""
        elems = s["elems"]
        k = s.get("squeezed", -1)
        if k >= 0:
            j = det_at(x, self.tets, self.D, elems[k])
            if j < floor:
                return j
        min_j, below = min_det_below(x, self.tets, self.D, elems, floor)
        if below >= 0:
            s["squeezed"] = int(below)
        return min_j

    def _say_short(self, short: float, scale: float) -> None:
        """One line when the grabbed nodes stay short of their targets because reaching them would turn
        elements inside out (a truly inverting pull), naming how far short; cleared once they arrive."""
        if short > 1e-6 * scale and self._short_frames >= 1:
            units = {1e-3: " mm", 1.0: " m"}.get(self.unit, " mesh units")
            self.notice = (
                f"hybrid: the pull of {len(self.grab_ids)} grabbed nodes would turn elements inside out; "
                f"the tool holds them {short / self.unit:.3g}{units} short of the target"
            )
        elif short <= 1e-6 * scale and self.notice.startswith("hybrid: the pull"):
            self.notice = ""
        # counted to 2 only (the notice waits one frame): a count that grew would make each frame differ
        self._short_frames = min(self._short_frames + 1, 2) if short > 1e-6 * scale else 0

    def _local_step(self, x: np.ndarray, elems: np.ndarray, rhs: np.ndarray) -> tuple[float, float]:
        """One local step over `elems` into rhs (kernels.twolevel.local_forces): (energy, smallest det F)."""
        return local_forces(
            x, self.tets, self.D, elems, self.w_arap, self.w_vol, self.quats, self.rotation_iterations, rhs, J_BARRIER
        )

    def _evaluate(self, s: dict, x: np.ndarray) -> tuple[float, float, np.ndarray]:
        """The energy, the smallest det F and the forces on the solved nodes at x (one local step)."""
        free = s["free"]
        rhs = self._rhs if self._rhs is not None and self._rhs.shape == x.shape else np.zeros_like(x)
        self._rhs = rhs
        energy, min_j = self._local_step(x, s["elems"], rhs)
        # forces on the solved nodes: f = rhs - L x (minus the energy's gradient)
        xf = x[free]
        Lx = np.empty_like(xf)
        spmv3(*s["L_ff"], xf, Lx)
        f = rhs[free] - Lx - _spmv3(s["L_fo"], x)
        self._cache = (s, float(energy), float(min_j), f)
        return float(energy), float(min_j), f

    def _iterate(self, s: dict, x: np.ndarray, scale: float) -> tuple[int, float, np.ndarray]:
        """The frame's nonlinear iterations: each a two-level step (coarse correction, CG smoothing) taken
        as far along as a backtracking line search allows, so that the energy falls (Armijo) and no
        element falls below J_FLOOR (or below where it already was). The coarse step is a Newton step with
        the rest Hessian: far from rest (a large rotation, nu near 0.5) it can point uphill or overshoot,
        and without the search the iteration flickered between two shapes under a still tool and
        overshot a far pull threefold. When even a short two-level step does not descend, the CG step of
        projective dynamics' own global matrix does (its quadratic model bounds the energy from above
        for the current rotations). Returns (iterations, largest step, the frame's step)."""
        free = s["free"]
        c = self._cache
        if c is not None and c[0] is s:
            energy, min_j, f = c[1], c[2], c[3]
        else:
            energy, min_j, f = self._evaluate(s, x)
        self._f_peak = max(self._f_peak, float(np.max(np.abs(f), initial=0.0)))
        total = np.zeros((len(free), 3))
        done, last = 0, 0.0
        for _ in range(self.iterations):
            done += 1
            base = x[free].copy()
            taken = 0.0
            for d in self._directions(s, f):
                slope = float(np.sum(f * d))
                if not slope > 0.0:
                    continue
                taken, e1, j1, f1 = self._line_search(s, x, base, d, slope, energy, min_j)
                if taken:
                    break
            if not taken:  # no step descends: at the energy's answer, as far as round-off tells, if the
                # forces are gone too; otherwise (rotations refined too little for the energy to tell a
                # short step's gain, nearly incompressible) the next frame tries again
                x[free] = base
                energy, min_j, f = self._evaluate(s, x)
                self._conjugate = None
                self._converged = self._balanced(f)
                break
            step = taken * d
            # the direction taken, and the preconditioned forces and forces it was made from: the next
            # iteration's conjugate-gradient share (see _directions)
            self._conjugate = (s, d, self._z, f) if self._z is not None else None
            total += step
            energy, min_j, f = e1, j1, f1
            size = float(np.max(np.abs(step)))
            # converging linearly at rate rho, at most |step| rho / (1 - rho) is left to go
            rate = size / self._prev_step if self._prev_step > 0.0 else 1.0
            self._prev_step = size
            remaining = size * rate / (1.0 - rate) if rate < 1.0 else math.inf
            last = max(last, size)
            if max(size, remaining) <= REST_TOLERANCE * scale and self._balanced(f):
                self._converged = True  # at rest under a still tool: later frames cost nothing
                break
        return done, last, total

    def _line_search(
        self, s: dict, x: np.ndarray, base: np.ndarray, d: np.ndarray, slope: float, energy: float, min_j: float
    ) -> tuple[float, float, float, np.ndarray]:
        """Move the solved nodes to base + alpha d for the largest alpha tried that lowers the energy
        (Armijo; an unknown energy, nan, is not tested) and keeps det F above J_FLOOR (or where it was).
        Returns (alpha, 0 if none held, and the energy, smallest det F and forces there)."""
        free = s["free"]
        alpha, secant, good = 1.0, True, None
        e1, j1, f1 = energy, min_j, np.zeros_like(d)
        for _ in range(LINE_HALVINGS + 2):
            x[free] = base + alpha * d
            e1, j1, f1 = self._evaluate(s, x)
            descends = math.isnan(energy) or e1 <= energy - ARMIJO * alpha * slope + 1e-12 * abs(energy)
            ok = descends and j1 >= min(J_FLOOR, min_j)
            if secant:
                secant = False
                # the energy's curvature along d from the slopes at both ends gives its minimum on the
                # line: a step that overshoots it (the rest Hessian's coarse step far from rest) is
                # shortened to it, one that falls well short is lengthened, once
                curv = (slope - float(np.sum(f1 * d))) / alpha
                best = slope / curv if curv > 0.0 else 2.0 * alpha
                if best < 0.7 * alpha or (ok and best > 1.4 * alpha):
                    good = (alpha, e1, j1, f1) if ok else None
                    alpha = min(max(best, 0.05 * alpha), 2.0 * alpha)
                    continue
            if ok:
                return alpha, e1, j1, f1
            if good is not None:  # the lengthened step failed: back to the one that held
                x[free] = base + good[0] * d
                self._cache = (s, *good[1:])
                return good
            alpha *= 0.5
        return 0.0, e1, j1, f1

    def _directions(self, s: dict, f: np.ndarray):
        """The steps the line search tries, in order, each made only if the one before it fails: the
        two-level step z carried on along the last direction p (under a still target), the two-level step
        alone, projective dynamics' CG step.

        The share of p is Polak-Ribiere's, f . (z - z_prev) / (f_prev . z_prev), never below 0 (a restart):
        with the two-level step as the preconditioner the iterations are nonlinear preconditioned CG. The
        two-level step alone under-steps the smooth, nearly volume-keeping part of a stiff body's answer,
        whose error then falls by a constant factor a frame; the conjugate share carries it on. On the
        study's 10,625-node block lifted 3 mm at nu 0.499: 13 frames to 10 % of the energy's answer and 37
        to 1 %, where a fixed half of the last step (heavy ball) took 28 and 146; at nu 0.45 2
        and 6 frames against 3 and 6 (tools/study/long_runs.py, the stiffness part). Polak-Ribiere rather
        than Fletcher-Reeves: the smoothing's few CG steps make the preconditioner change with f, which
        Polak-Ribiere's difference of z tolerates."""
        if s["coarse"] is not None:
            z = self._direction(s, f, True)
            self._z = z
            m = self._conjugate if self._conjugate is not None and self._conjugate[0] is s else None
            if m is not None:
                _, p_prev, z_prev, f_prev = m
                den = float(np.sum(f_prev * z_prev))
                beta = max(0.0, float(np.sum(f * (z - z_prev))) / den) if den > 0.0 else 0.0
                if beta > 0.0:
                    yield z + beta * p_prev
            yield z
        self._z = None  # the last resort is no two-level step: the next iteration restarts
        yield self._direction(s, f, False)

    def _balanced(self, f: np.ndarray) -> bool:
        """Whether the forces left are a small share of the largest seen since the targets last moved: a
        step-size test alone is fooled by an iteration that crawls (its steps are small, its distance to
        the answer is not)."""
        return float(np.max(np.abs(f), initial=0.0)) <= REST_FORCE * self._f_peak

    def _direction(self, s: dict, f: np.ndarray, coarse: bool) -> np.ndarray:
        """The two-level step for forces f on the solved nodes (not applied): the coarse step, then CG
        smoothing of what is left (updated linearly through K) with K itself; with coarse=False, CG on
        projective dynamics' global matrix alone (for the current rotations its quadratic bounds the
        energy from above, so that step always descends: the line search's last resort)."""
        indptr, indices, data = s["L_ff"]
        r, z, p, q, d = s["scratch"]
        step = np.zeros_like(f)
        if coarse and s["coarse"] is not None:
            KP, P, factor = s["coarse"]
            y = factor.solve(_spmv3(P[1], f).ravel()).reshape(-1, 3)
            f = f - _bspmv3(KP, y)
            step += _spmv3(P[0], y)
        if coarse and s["coarse"] is not None:
            # smoothing with the rest stiffness: it knows the volume term's coupling of the axes, where
            # projective dynamics' matrix stiffens every direction by it (at nu 0.49 on the 1.5k-node
            # block: 12 frames to 1 % of the energy's answer against 35; at 0.499, 36 frames to 10 %
            # where the other never got there)
            block_pcg(*s["K_ff"], f, d, self.cg_iterations, r, z, p, q)
            return step + d
        d[:] = 0.0
        pcg3(indptr, indices, data, s["inv_diag"], f, d, self.cg_iterations, 1e-10, r, z, p, q)
        step += d
        return step

    def _sleep_or_wake(self, s: dict, x: np.ndarray, scale: float, last: float) -> None:
        """After a frame: wake the sleepers the disturbance reached, or put a body at rest to sleep.

        A node wakes its sleeping neighbours when it has moved more than the threshold since it last did
        (or since it woke), not in one frame: under a slow drag each frame's motion at the front is far
        below any threshold, and a per-frame test left all but the nodes around the tool asleep (125 of
        10,648 nodes moved under a 4 mm drag over 25 frames, 86 % from the same body awake)."""
        # measured against the largest displacement since the body last slept: after a release the
        # body's own displacement shrinks towards zero, and a threshold relative to it never falls
        self._sleep_scale = max(self._sleep_scale, scale)
        threshold = self.sleep * self._sleep_scale
        free = s["free"]
        drift = np.zeros(self.n)
        drift[free] = np.sqrt(np.sum((x[free] - self._anchor[free]) ** 2, axis=1))
        before = self.awake.copy()
        # the sleepers beyond the front hold the front's own nodes back, so a node tells its sleeping
        # neighbours the largest drift within DRIFT_RINGS rings inside it: that is how far the
        # disturbance moves the body where nothing holds it back
        drift = ring_max(self.graph.indptr, self.graph.indices, free, drift, DRIFT_RINGS)
        woke = wake_front(self.graph.indptr, self.graph.indices, self.awake, drift, threshold, self.wake_rings)
        if woke:
            self._setup = None
            loose = ~self.fixed
            if np.count_nonzero(self.awake & loose) >= WAKE_ALL * np.count_nonzero(loose):
                # a front that has crossed most of the body would grow a little every frame, and each
                # new awake set costs a new coarse factorisation (147-181 ms a frame on two threads at 10k
                # nodes, where the whole body costs 12): the rest is woken at once, so the set, and with
                # it the cached set-up, stays the same while the tool holds
                self.awake[:] = True
            spoke = free[drift[free] > threshold]
            self._anchor[spoke] = x[spoke]  # these told their neighbours: their drift counts afresh
            new = self.awake & ~before
            self._anchor[new] = x[new]
        # converging linearly, about last * rate / (1 - rate) is still to go: a body that creeps
        # slowly is not at rest, and freezing it would keep the creep's shape
        rate = last / self._prev_last if self._prev_last > 0.0 else 1.0
        remaining = last / (1.0 - rate) if rate < 1.0 else math.inf
        self._prev_last = last
        if not woke and len(self.grab_ids) == 0 and remaining <= threshold:
            self.awake[:] = False  # nothing held and nothing moving: the body sleeps
            self._setup = None
            self._sleep_scale = 0.0

    def _settle_at_rest(self) -> bool:
        """After the last release, with every fixed node where it rests, the static answer is known
        exactly: nothing holds the body, no load acts on it, and the rest shape is the energy's minimum
        (zero, cut elements or not). So the body goes there in the frame of the release rather than
        iterating back over many frames (the creep a few smoothing steps a frame would show). Returns
        whether it did."""
        rest = self.rest * self.unit
        if len(self.grab_ids) or not np.allclose(
            self.x[self.fixed], rest[self.fixed], rtol=0.0, atol=1e-12 * self._scale
        ):
            return False
        self.x[:] = rest
        self._far_u[:] = 0.0
        self._far_Y = None
        self._cache, self._converged = None, False
        self.quats[:] = 0.0
        self.quats[:, 0] = 1.0
        if self.sleep:
            self.awake[:] = False
            self._sleep_scale = 0.0
        self._setup = None
        self._prev_last = 0.0
        np.divide(self.x, self.unit, out=self._positions)
        return True

    def _cut(self, p0, p1, normal, depth) -> int:
        killed = super()._cut(p0, p1, normal, depth)
        if killed:
            self._cache, self._converged = None, False
            self._setups.clear()
            self._setup = None
        return killed

    def reset(self) -> None:
        super().reset()
        self._at_rest = True
        self._cache = None
        self._converged = False
        self._prev_step = 0.0
        self._short_frames = 0
        if self.sleep:
            self.awake[:] = False
        self._far_u[:] = 0.0
        self._far_Y = None
        self._setup = None
        self._synced = None
        self._last_targets = None


def _coarse_operators(K_ff: sp.csr_matrix, ids: np.ndarray, cw: np.ndarray) -> tuple:
    """The coarse step's operators for the solved nodes, whose coarse nodes and trilinear weights are ids
    and cw (nf, 8): K P as 3 x 3 blocks, P and P^T (CSR arrays), and the factorised P^T K P. The frame's
    products with them run in numba's threads, rows apart, so the same bits whatever their number (in
    scipy's single thread they were a sixth of a dragged frame on one thread at 10k nodes)."""
    nf = len(ids)
    used, cidx = np.unique(ids, return_inverse=True)
    P = sp.csr_matrix((cw.ravel(), (np.repeat(np.arange(nf), 8), cidx.ravel())), shape=(nf, len(used)))
    P3 = sp.kron(P, sp.eye(3), format="csr")
    KP = (K_ff @ P3).tocsr()  # the coarse step's force change K P y in one product with fewer entries
    Kc = (P3.T @ KP).tocsc()
    cd = Kc.diagonal()
    if np.any(cd <= 1e-300 * max(cd.max(), 1e-300)):
        Kc = Kc + sp.diags(np.where(cd <= 1e-300 * max(cd.max(), 1e-300), 1.0, 0.0))
    # a small awake region can cover fewer solved nodes than coarse nodes, so that P^T K P has
    # directions y with P y = 0: singular, but the forces never reach them (f . P y = 0). A shift
    # of 1e-10 of the largest diagonal keeps the factorisation defined and gives them no step
    Kc = (Kc + sp.diags(np.full(Kc.shape[0], 1e-10 * cd.max()))).tocsc()
    factor = splu(Kc, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    KPb = KP.tobsr(blocksize=(3, 3))
    KPb.sort_indices()
    blocks = (KPb.indptr.astype(np.int64), KPb.indices.astype(np.int64), np.ascontiguousarray(KPb.data))
    return blocks, (_csr(P), _csr(P.T.tocsr())), factor


def _csr(A: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A CSR matrix's arrays as the kernels take them (sorted int64 indices, contiguous values)."""
    A = A.tocsr()
    A.sort_indices()
    return A.indptr.astype(np.int64), A.indices.astype(np.int64), np.ascontiguousarray(A.data, dtype=np.float64)


def _spmv3(A: tuple[np.ndarray, np.ndarray, np.ndarray], x: np.ndarray) -> np.ndarray:
    """A x for a matrix from `_csr` and x (n, 3), in numba's threads."""
    out = np.empty((len(A[0]) - 1, 3))
    spmv3(*A, np.ascontiguousarray(x), out)
    return out


def _bspmv3(A: tuple[np.ndarray, np.ndarray, np.ndarray], y: np.ndarray) -> np.ndarray:
    """A y for a matrix of 3 x 3 blocks (indptr, indices, blocks) and y (n, 3), in numba's threads."""
    out = np.empty((len(A[0]) - 1, 3))
    bspmv3(*A, np.ascontiguousarray(y), out)
    return out
