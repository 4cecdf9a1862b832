"""ChainMail parameters shared by every front end: order names and the material-limit checks (thesis 5.2.2),
from their declaration in chainsim.systems.engine.model_params."""

from __future__ import annotations

import math

from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.model_params import ORDER_ALIASES, ORDER_CHOICES, ORDERS, params

__all__ = ["ORDERS", "ORDER_ALIASES", "ORDER_CHOICES", "order_name", "order_code", "check_finite", "check_material"]


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
    """alpha_min in [0, 1], alpha_max >= 1, beta >= 0, all finite (their declaration in model_params);
    `prefix` names them as the user wrote them."""
    decl = params("chainmail")
    for key, v in (("alpha_min", alpha_min), ("alpha_max", alpha_max), ("beta", beta)):
        decl[key].check(v, label=f"{prefix}{key.replace('_', '-')}")
