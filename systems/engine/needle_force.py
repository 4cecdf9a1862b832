"""The needle's axial force: capsule stiffness, cutting at the tip and friction along the shaft.

The decomposition is Okamura, Simone and O'Leary's (IEEE TBME 51(10), 2004): before a layer is punctured
its boundary is a spring pressed by the tip; while the tip advances through a layer it cuts at that
layer's constant cutting force; along the inserted length the shaft rubs with a modified Karnopp
friction (per unit length, so it grows with depth). One evaluation is a pure function of a few numbers
and per-layer arrays (nopython, no allocation), so a haptic loop can call it at 1 kHz beside the 60 Hz
tissue (the 50 us budget of `chainsim bench needle`).

Stiffness of a layer boundary, from the layer's material: a rigid flat punch of radius a pressed
into an elastic half-space needs F = 2 a E delta / (1 - nu^2) (Boussinesq's solution; Johnson,
Contact Mechanics, 1985, eq. 3.38), with a the radius over which skin under a needle carries load.

A boundary with little tissue behind it before bone (`room` mm along the needle) stiffens as the press
closes that gap: F = k tent room / (room - tent), which is k tent for a small press and grows without
bound as the tissue left under the tip vanishes, so every layer gives before the tip is pressed
through it onto bone (a chosen form with the right limits; thin layers on a rigid base stiffen, as in
Hayes et al., J Biomech 1972).

Karnopp friction, per mm of inserted length L in each layer:
    |v| >  dv: F = L * (C + b |v|) sign(v)     (sliding: dynamic friction plus viscous drag)
    |v| <= dv: F = clip(stick, -L D, L D)      (sticking: the tissue's own elastic pull on the shaft,
                                                at most the static friction D per mm)
`stick` is what the tissue held on the shaft pulls with (the needle-tissue coupling supplies it).
Positive forces resist insertion.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import ArrayLike


def punch_stiffness(E_kpa: float, nu: float, radius_mm: float) -> float:
    """N/mm of a rigid flat punch of `radius_mm` on a half-space of modulus E (kPa) and ratio nu."""
    return 2.0 * radius_mm * (E_kpa * 1e-3) / (1.0 - nu * nu)


@njit(cache=True, nogil=True)
def press_force(k, tent, room):
    """N to press a boundary of stiffness k (N/mm) by `tent` mm with `room` mm of tissue behind it."""
    if tent <= 0.0:
        return 0.0
    if tent >= room:
        return np.inf
    if room == np.inf:
        return k * tent
    return k * tent * room / (room - tent)


@njit(cache=True, nogil=True)
def axial_force(tent, k_tent, room, advancing, cutting, lengths, dyn, visc, static, v, dv, stick):
    """Axial force (N) on the needle and its three terms (stiffness, cutting, friction).

    tent: mm the unpunctured boundary under the tip is pressed (0: none); k_tent: its stiffness (N/mm);
    room: tissue behind it along the needle (mm, inf: none to speak of);
    advancing: the tip is moving forward inside a layer, cutting it; cutting: that layer's cutting
    force (N); lengths, dyn, visc, static: per layer, inserted length (mm), dynamic friction (N/mm),
    viscous friction (N s/mm^2) and static friction (N/mm); v: insertion speed (mm/s, negative
    withdrawing); dv: half-width of the sticking band (mm/s); stick: the tissue's pull on the shaft (N)."""
    f_stiff = press_force(k_tent, tent, room)
    f_cut = cutting if advancing else 0.0
    f_fric = 0.0
    if abs(v) > dv:
        s = 1.0 if v > 0.0 else -1.0
        for i in range(lengths.shape[0]):
            f_fric += lengths[i] * (dyn[i] + visc[i] * abs(v)) * s
    else:
        cap = 0.0
        for i in range(lengths.shape[0]):
            cap += lengths[i] * static[i]
        f_fric = min(max(stick, -cap), cap)
    return f_stiff + f_cut + f_fric, f_stiff, f_cut, f_fric


def evaluate(
    tent: float,
    k_tent: float,
    room: float,
    advancing: bool,
    cutting: float,
    lengths: ArrayLike,
    dyn: ArrayLike,
    visc: ArrayLike,
    static: ArrayLike,
    v: float,
    dv: float,
    stick: float,
) -> tuple[float, float, float, float]:
    """`axial_force` with its arguments made the types the kernel is compiled for."""
    return axial_force(
        float(tent), float(k_tent), float(room), bool(advancing), float(cutting),
        np.ascontiguousarray(lengths, dtype=np.float64), np.ascontiguousarray(dyn, dtype=np.float64),
        np.ascontiguousarray(visc, dtype=np.float64), np.ascontiguousarray(static, dtype=np.float64),
        float(v), float(dv), float(stick),
    )  # fmt: skip
