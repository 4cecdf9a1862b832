"""The one declaration of every deformation model's parameters: name, type, range, default, units, help.

Each model (chainmail, xpbd, projective, hybrid, surface) lists the settings its body takes. The body
constructors take their defaults from here, `make_body` checks what it is given against it, the
manifest's [materials] keys and the `deformable` component's model keys are built from it
(`manifest_spec`), and `chainsim docs models` prints it (`markdown`, the tables in
docs/choosing-a-model.md). A parameter whose pack default differs from the body's (a pack's
`unit` is millimetres, its `relax` 2, its `iterations` 0 for "the model's own") says so in
`pack_default`, beside the body's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from chainsim.systems.engine import limits
from chainsim.systems.engine.errors import UserError

KINDS = ("float", "int", "bool", "enum")
#: ChainMail's waiting-list orders by name, in the kernels' code order (kernels.chainmail ORDER_*)
ORDERS = ("breadth-first", "balanced", "schill", "depth-first")
#: older names still accepted wherever an order is named
ORDER_ALIASES = {"fifo": "breadth-first"}
#: every name a user may give: the orders, then their aliases
ORDER_CHOICES = ORDERS + tuple(ORDER_ALIASES)
_SAME = object()  # pack_default not given: the pack's default is the body's


@dataclass(frozen=True, slots=True)
class Param:
    """One setting of a model's body."""

    name: str
    kind: str  # one of KINDS
    default: Any
    help: str
    units: str = ""
    min: float | None = None
    max: float | None = None
    choices: tuple = ()
    pack_default: Any = _SAME  # the manifest's default where it differs from the body's
    auto: bool = False  # the word "auto" is taken too (the body chooses, as with 0)

    @property
    def manifest_default(self) -> Any:
        return self.default if self.pack_default is _SAME else self.pack_default

    def range_text(self) -> str:
        if self.min is not None and self.max is not None:
            return f"[{self.min:g}, {self.max:g}]"
        if self.min is not None:
            return f">= {self.min:g}"
        if self.max is not None:
            return f"<= {self.max:g}"
        return ""

    def check(self, value: Any, where: str = "", label: str = "") -> None:
        """UserError naming `where`+name (or `label`, the name as the user wrote it) unless `value` is of
        this kind and within range."""
        name = label or f"{where}{self.name}"
        if self.auto and value == "auto":
            return
        if self.kind == "enum":
            if value not in self.choices:
                raise UserError(f"{name}: expected one of {', '.join(map(str, self.choices))}, got {value!r}")
            return
        if self.kind == "bool":
            if not isinstance(value, bool):
                raise UserError(f"{name}: expected true or false, got {value!r}")
            return
        if isinstance(value, bool) or not isinstance(value, int | float) and not hasattr(value, "__float__"):
            raise UserError(f"{name}: expected a number{' or auto' if self.auto else ''}, got {value!r}")
        v = float(value)
        if not math.isfinite(v):
            raise UserError(f"{name}: must be a finite number, got {value}")
        if self.kind == "int" and v != int(v):
            raise UserError(f"{name}: expected a whole number, got {value!r}")
        lo_bad = self.min is not None and v < self.min
        hi_bad = self.max is not None and v > self.max
        if lo_bad or hi_bad:
            rng = self.range_text()
            raise UserError(f"{name}: must be {'in ' + rng if rng.startswith('[') else rng}, got {v:g}")


# -- the parameters, grouped where models share them ------------------------------------------------------

ALPHA_MIN = Param(
    "alpha_min",
    "float",
    0.8,
    "Compression limit: a link may shrink to this fraction of its rest length (thesis 5.2.2).",
    min=0.0,
    max=1.0,
)
ALPHA_MAX = Param(
    "alpha_max", "float", 1.2, "Stretch limit: a link may grow to this fraction of its rest length.", min=1.0
)
BETA = Param("beta", "float", 0.1, "Shear limit: sideways offset allowed, as a fraction of the rest length.", min=0.0)
RELAX = Param(
    "relax",
    "int",
    0,
    "Relaxation iterations after each cascade (thesis 5.2.5).",
    min=0,
    max=limits.MAX_RELAX,
    pack_default=2,
)
EXACT = Param(
    "exact",
    "bool",
    False,
    "After each cascade and relaxation put every link back inside its limits (a pull past what the limits "
    "allow from the fixed elements stops at the nearest reachable point).",
)
ORDER = Param(
    "order",
    "enum",
    "breadth-first",
    "Waiting-list order: breadth-first (a queue; fifo is the same), depth-first (5.2.3 as written: new "
    "neighbours at the front), balanced (round robin of Fig. 5.3), schill (largest violation first).",
    choices=ORDER_CHOICES,
)
RELAX_STEP = Param(
    "relax_step", "float", 1.0, "Fraction of the way to the relaxed position per iteration.", min=0.0, max=1.0
)
DEPTH = Param("depth", "int", 2, "Branch depth per turn for the balanced order.", min=1, max=limits.MAX_BRANCH_DEPTH)
DTYPE = Param("dtype", "enum", "float64", "Precision of positions.", choices=("float64", "float32"))

E = Param("E", "float", 3000.0, "Young's modulus.", units="Pa", min=1e-6, max=1e12)
NU = Param("nu", "float", 0.45, "Poisson's ratio, 0 <= nu < 0.5.", min=0.0, max=0.4999)
DENSITY = Param("density", "float", 1000.0, "Mass density.", units="kg/m^3", min=1e-6, max=1e6)
UNIT = Param("unit", "float", 1.0, "Metres per mesh length unit.", units="m", min=1e-9, max=1e3, pack_default=0.001)
DAMPING = Param("damping", "float", 0.05, "Velocity damping per step.", min=0.0, max=0.99)
THICKNESS = Param("thickness", "float", 1.0, "Sheet thickness (surfaces).", units="mesh units", min=1e-9, max=1e6)
CG_ITERATIONS = Param(
    "cg_iterations", "int", 20, "Conjugate-gradient steps per global step (solver = cg).", min=1, max=10_000
)
ROTATION_ITERATIONS = Param(
    "rotation_iterations",
    "int",
    4,
    "Iterations of the per-tetrahedron rotation fit in each local step.",
    min=1,
    max=100,
)

XPBD_CONSTRAINTS = ("auto", "corotational", "neohookean", "stvk")
PROJECTIVE_SOLVERS = ("direct", "cg")
HYBRID_STARTS = ("none", "chainmail", "linear")

CHAINMAIL = (ALPHA_MIN, ALPHA_MAX, BETA, RELAX, EXACT, ORDER, RELAX_STEP, DEPTH, DTYPE)
XPBD = (
    E,
    NU,
    DENSITY,
    DAMPING,
    Param(
        "substeps",
        "int",
        "auto",
        "Substeps per simulation step, or auto: as many as the element size and stiffness need "
        "(docs/choosing-a-model.md).",
        min=1,
        max=1000,
        auto=True,
        pack_default=0,
    ),
    Param("iterations", "int", 1, "Iterations per substep.", min=1, max=1000, pack_default=0),
    THICKNESS,
    Param("bending", "float", 0.01, "Bending stiffness of surfaces, relative to stretching.", min=0.0, max=1e6),
    UNIT,
    Param(
        "constraints",
        "enum",
        "auto",
        "Tetrahedron energy: corotational, neohookean (stable Neo-Hookean) or stvk (Green strain); auto: corotational.",
        choices=XPBD_CONSTRAINTS,
    ),
)
PROJECTIVE = (
    E,
    NU,
    DENSITY,
    DAMPING,
    Param("iterations", "int", 10, "Local-global iterations per step.", min=1, max=10_000, pack_default=0),
    Param("dynamic", "bool", True, "Integrate inertia (false: statics, the shape each frame settles to)."),
    UNIT,
    THICKNESS,
    Param(
        "solver",
        "enum",
        "auto",
        "Global step by a prefactorised sparse solve (direct: fewest frames to settle) or warm-started "
        "conjugate gradients (cg: no factorisation, cheaper frames, more of them); auto: direct up to 25,000 "
        "free nodes, cg above (docs/choosing-a-model.md).",
        choices=("auto", *PROJECTIVE_SOLVERS),
        pack_default="direct",
    ),
    CG_ITERATIONS,
    ROTATION_ITERATIONS,
)
HYBRID = (
    E,
    NU,
    DENSITY,
    Param("iterations", "int", 1, "Two-level iterations per frame.", min=1, max=10_000, pack_default=0),
    Param("cg_iterations", "int", 6, "CG smoothing steps per iteration.", min=1, max=10_000),
    Param("rotation_iterations", "int", 3, "Rotation-fit iterations in each local step.", min=1, max=100),
    Param(
        "coarse",
        "float",
        "auto",
        "Coarse-grid spacing in mean edge lengths (0: no coarse correction; otherwise 1.5..16); auto: 3, or 2 "
        "for nearly incompressible tissue (nu >= 0.497), whose volume a coarser trilinear grid cannot follow "
        "(docs/choosing-a-model.md).",
        min=0.0,
        max=16.0,
        auto=True,
    ),
    Param("start", "enum", "linear", "Start of each frame: none, chainmail or linear.", choices=HYBRID_STARTS),
    Param(
        "sleep",
        "float",
        0.0,
        "Nodes moving less than this share of the displacement scale sleep (0: off).",
        min=0.0,
        max=0.999,
    ),
    Param("wake_rings", "int", 4, "Rings of neighbours woken around a moving node.", min=1, max=1000),
    UNIT,
    ALPHA_MIN,
    ALPHA_MAX,
    BETA,
)
SURFACE = (ALPHA_MIN, ALPHA_MAX, BETA, RELAX, EXACT, ORDER)

#: every model's parameters, by model name
MODEL_PARAMS: dict[str, tuple[Param, ...]] = {
    "chainmail": CHAINMAIL,
    "xpbd": XPBD,
    "projective": PROJECTIVE,
    "hybrid": HYBRID,
    "surface": SURFACE,
}
#: the models, in the order they are offered everywhere
MODELS = tuple(MODEL_PARAMS)
#: what each model is, one line (docs)
MODEL_HELP = {
    "chainmail": "Generalised ChainMail on the mesh's links (thesis 5.2); limits may be given per link.",
    "xpbd": "XPBD on tetrahedra or a triangle sheet.",
    "projective": "Projective dynamics on tetrahedra or a triangle sheet.",
    "hybrid": "Static projective dynamics with a linear start, a coarse correction and sleeping (tetrahedra only).",
    "surface": "SurfaceChainMail on a triangle sheet (thesis 4.4); limits may be given per link.",
}
#: where a pack sets each model's parameters: a [materials] entry or the entity's `deformable` table (the
#: others keep the body's default in a pack, or take an `auto` row's value)
_VOLUME_KEYS = ("E", "nu", "density", "damping", "iterations", "unit", "thickness")
#: the ChainMail keys of a [materials] entry (the manifest's [materials] fields and the tissue's materials)
MATERIAL_KEYS = ("alpha_min", "alpha_max", "beta", "relax", "exact")
PACK_TABLE: dict[str, dict[str, str]] = {
    "chainmail": {
        **dict.fromkeys(MATERIAL_KEYS, "materials"),
        **dict.fromkeys(("order", "relax_step", "depth", "dtype"), "deformable"),
    },
    "xpbd": dict.fromkeys((*_VOLUME_KEYS, "substeps"), "deformable"),
    "projective": dict.fromkeys((*_VOLUME_KEYS, "solver", "cg_iterations", "rotation_iterations"), "deformable"),
    "hybrid": dict.fromkeys(("E", "nu", "density", "iterations", "unit"), "deformable"),
    "surface": {
        **dict.fromkeys(MATERIAL_KEYS, "materials"),
        "order": "deformable",
    },
}
#: ChainMail limits that may be arrays of one value per link
PER_LINK = ("alpha_min", "alpha_max", "beta")


def model_name(model: str) -> str:
    """`model` if it is a model, else one UserError line listing the models."""
    if model not in MODEL_PARAMS:
        raise UserError(f"model: expected one of {', '.join(MODELS)}, got {model!r}")
    return model


def params(model: str) -> dict[str, Param]:
    """The parameters of `model` by name."""
    return {p.name: p for p in MODEL_PARAMS[model_name(model)]}


def defaults(model: str) -> dict[str, Any]:
    """The body's default for each parameter of `model`."""
    return {p.name: p.default for p in MODEL_PARAMS[model_name(model)]}


def settings(model: str, given: dict[str, Any], where: str = "") -> dict[str, Any]:
    """The entries of `given` that `model` takes, each checked against its declaration (per-link limits
    of ChainMail and SurfaceChainMail may be arrays: each value is checked). Others are left out, so one
    set of settings can build any model."""
    decl = params(model)
    out = {}
    for k, v in given.items():
        p = decl.get(k)
        if p is None:
            continue
        if k in PER_LINK and np.ndim(v):
            arr = np.asarray(v, dtype=np.float64)
            for x in (float(arr.min()), float(arr.max())) if arr.size else ():
                p.check(x, where)
        else:
            p.check(v, where)
        out[k] = v
    return out


def manifest_spec(name: str, models: tuple[str, ...] = ("chainmail",), *, prefix: bool = False) -> dict[str, Any]:
    """A manifest key's kind, default, units, help, choices and range from the declaration of `name` in
    `models` (the deformable component and [materials] build their fields from it): the range every
    model allows (widened to the pack default, which may mean "the model's own"), the help of each model
    (`prefix`: named by model)."""
    ps = [params(m)[name] for m in models]
    first = ps[0]
    default = first.manifest_default
    lo = max((p.min for p in ps if p.min is not None), default=None)
    hi = min((p.max for p in ps if p.max is not None), default=None)
    if first.kind in ("int", "float") and not isinstance(default, bool):
        if lo is not None and default < lo:
            lo = default
        if hi is not None and default > hi:
            hi = default
    if all(p == first for p in ps):
        help_ = f"{'/'.join(models)}: {first.help}" if prefix else first.help
    else:
        help_ = "; ".join(f"{m}: {p.help[:-1] if p.help.endswith('.') else p.help}" for m, p in zip(models, ps))
        help_ += "."
    own = [f"{m} {p.default}" for m, p in zip(models, ps) if p.pack_default is not _SAME and p.default != default]
    if own and default == 0:
        help_ += f" 0: the model's own ({', '.join(own)})."
    return dict(kind=first.kind, default=default, units=first.units, help=help_, choices=first.choices, min=lo, max=hi)


def markdown() -> str:
    """Every model's parameters as markdown tables (`chainsim docs models`, docs/choosing-a-model.md)."""
    out = []
    for model, ps in MODEL_PARAMS.items():
        out += [f"### `{model}`", "", MODEL_HELP[model], ""]
        out += ["| parameter | type | range | units | default | in a pack (default there) | meaning |"]
        out += ["|---|---|---|---|---|---|---|"]
        for p in ps:
            kind = p.kind + (f" ({', '.join(p.choices)})" if p.choices else "")
            table = PACK_TABLE[model].get(p.name)
            pack = f"`[materials]` ({_fmt(p.manifest_default)})" if table == "materials" else "no"
            if table == "deformable":
                pack = f"`deformable` ({_fmt(p.manifest_default)})"
            out.append(
                f"| `{p.name}` | {kind} | {p.range_text()} | {p.units} | {_fmt(p.default)} | {pack} | {p.help} |"
            )
        out.append("")
    return "\n".join(out)


def _fmt(v: Any) -> str:
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return f"{v:g}"
    if isinstance(v, str):
        return f'"{v}"'
    return str(v)
