"""The study's baselines and its live models (XPBD, projective dynamics) on a scene.

Baselines set the floor a model must beat for its figure to mean anything: "only the grabbed patch
moves" (u = 0 elsewhere) and a distance-weighted blend of the grab displacement (each node moves by
d_fixed / (d_fixed + d_grab) of it, no physics). The live models run through the body API the
simulator uses, frame by frame from rest at 60 Hz, until their positions settle; a row keeps the
cost per frame, the frames it took, the settled field and the grab's reaction force.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from chainsim.systems.engine.bodies.projective import ProjectiveBody
from chainsim.systems.engine.bodies.xpbd import XPBDBody

FRAME_DT = 1.0 / 60.0
MAX_FRAMES = 1500
SETTLE = 1e-4  # a frame that moves no node more than this fraction of the imposed displacement


def baseline_patch(scene, strain: float) -> np.ndarray:
    """Only the grabbed patch moves."""
    u = np.zeros_like(scene.pos)
    u[scene.grabbed] = scene.grab_disp(strain)
    return u


def baseline_blend(scene, strain: float) -> np.ndarray:
    """Each node moves by d_fixed / (d_fixed + d_grab) of the grab displacement (no physics)."""
    d_f = cKDTree(scene.pos[scene.fixed]).query(scene.pos)[0] if len(scene.fixed) else np.full(len(scene.pos), 1e9)
    d_g = cKDTree(scene.pos[scene.grabbed]).query(scene.pos)[0]
    w = d_f / np.maximum(d_f + d_g, 1e-300)
    return w[:, None] * (strain * scene.length * scene.direction)[None, :]


#: the live settings the study runs, as the body arguments `auto` rebuilds them from
LIVE_PARAMS: dict[str, dict[str, Any]] = {
    "XPBD (8 substeps)": {"damping": 0.1, "substeps": 8},
    "projective (statics, 10 it)": {"iterations": 10, "dynamic": False},
}
LIVE = {
    "XPBD (8 substeps)": lambda s, E, nu: XPBDBody(
        s.pos, s.tets, E=E, nu=nu, fixed=s.fixed, **LIVE_PARAMS["XPBD (8 substeps)"]
    ),
    "projective (statics, 10 it)": lambda s, E, nu: ProjectiveBody(
        s.pos, s.tets, E=E, nu=nu, fixed=s.fixed, **LIVE_PARAMS["projective (statics, 10 it)"]
    ),
}


def settle(make, scene, strain: float, E: float, nu: float) -> tuple[np.ndarray, dict]:
    """Run a fresh body frame by frame after a grab until it settles; the field and the figures."""
    body = make(scene, E, nu)
    body.grab(scene.grabbed, scene.pos[scene.grabbed] + scene.grab_disp(strain))
    body.step(FRAME_DT)  # compile and warm outside the timing
    body = make(scene, E, nu)
    body.grab(scene.grabbed, scene.pos[scene.grabbed] + scene.grab_disp(strain))
    d = strain * scene.length
    frames, cpu, status = 0, 0.0, "max frames"
    while frames < MAX_FRAMES:
        frames += 1
        before = body.positions.copy()
        t0 = time.thread_time()
        body.step(FRAME_DT)
        cpu += time.thread_time() - t0
        if np.max(np.abs(body.positions - before)) < SETTLE * d:
            status = "settled"
            break
    force = body.grab_force()  # the reaction the settled grab needs (None for a model without forces)
    info = {"frames": frames, "ms_per_frame": 1e3 * cpu / frames, "status": status}
    if force is not None:
        info["grab_force_N"] = float(np.asarray(force) @ scene.direction)
    return body.positions - scene.pos, info
