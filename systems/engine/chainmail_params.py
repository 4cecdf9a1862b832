"""ChainMail parameters shared by every front end: order names and the material-limit checks (thesis 5.2.2)."""

from __future__ import annotations

import math

from chainsim.systems.engine.errors import UserError

#: waiting-list orders by name, in the kernels' code order (chainsim.systems.engine.kernels.chainmail ORDER_*)
ORDERS = ("breadth-first", "balanced", "schill", "depth-first")
#: older names still accepted wherever an order is named
ORDER_ALIASES = {"fifo": "breadth-first"}
#: every name a user may give: the orders, then their aliases
ORDER_CHOICES = ORDERS + tuple(ORDER_ALIASES)


def order_name(name: str) -> str:
    """The order's own name for `name` (an alias such as fifo becomes breadth-first)."""
    name = ORDER_ALIASES.get(name, name)
    if name not in ORDERS:
        raise UserError(f"order: expected one of {', '.join(ORDER_CHOICES)}, got {name!r}")
    return name


def order_code(name: str) -> int:
    """The kernels' ORDER_* code for an order name or alias."""
    return ORDERS.index(order_name(name))


def check_finite(name: str, v: float) -> None:
    if not math.isfinite(v):
        raise UserError(f"{name}: must be a finite number, got {v}")


def check_material(alpha_min: float, alpha_max: float, beta: float, prefix: str = "--") -> None:
    """alpha_min in [0, 1], alpha_max >= 1, beta >= 0, all finite; `prefix` names them as the user wrote them."""
    names = (f"{prefix}alpha-min", f"{prefix}alpha-max", f"{prefix}beta")
    for name, v in zip(names, (alpha_min, alpha_max, beta)):
        check_finite(name, v)
    if not 0.0 <= alpha_min <= 1.0:
        raise UserError(f"{names[0]}: must be in [0, 1], got {alpha_min:g}")
    if alpha_max < 1.0:
        raise UserError(f"{names[1]}: must be >= 1, got {alpha_max:g}")
    if beta < 0.0:
        raise UserError(f"{names[2]}: must be >= 0, got {beta:g}")
