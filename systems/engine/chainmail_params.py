"""ChainMail parameters shared by every front end: order names and the material-limit checks (thesis 5.2.2)."""

from __future__ import annotations

import math

from chainsim.engine.errors import UserError

#: waiting-list orders by name, in the kernels' code order (chainsim.engine.kernels.chainmail ORDER_*)
ORDERS = ("fifo", "balanced", "schill")


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
