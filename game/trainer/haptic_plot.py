"""The force profile of an attempt made with a force-feedback device, drawn: OUT/haptic_force.png.

Two panels from the servo's log (the needle procedure's haptics, its trace_csv): the force the
hand felt against the needle's depth (in and out), and against time, with each puncture marked where
the layer gave and the ticks held against bone shaded. `chainsim run --device ... --out DIR` writes it;
`chainsim bench haptics` draws its run the same way.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

PUNCTURE = 1  # chainsim.systems.engine.haptics.model.EV_PUNCTURE


def plot_trace(csv_path: Path, png_path: Path, title: str = "") -> None:
    """Draw the haptic trace at `csv_path` into `png_path`."""
    rows = np.genfromtxt(csv_path, delimiter=",", names=True)
    rows = np.atleast_1d(rows)
    t, depth, force = rows["time_s"], rows["tool_mm"], rows["force_N"]
    # each puncture marked where the layer gave: the tick before the force dropped
    pops = np.maximum(np.nonzero(rows["events"].astype(np.int64) & PUNCTURE)[0] - 1, 0)
    wall = rows["wall"] != 0
    fig, (ax_d, ax_t) = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    ax_d.plot(depth, force, lw=0.8, color="tab:blue")
    ax_d.plot(depth[pops], force[pops], "v", color="tab:red", label="puncture")
    ax_d.set_xlabel("needle depth (mm)")
    ax_d.set_ylabel("force on the hand against insertion (N)")
    ax_t.plot(t, force, lw=0.8, color="tab:blue")
    if wall.any():
        ax_t.fill_between(t, force.min(), force.max(), where=wall, color="0.85", label="held against bone")
    ax_t.plot(t[pops], force[pops], "v", color="tab:red", label="puncture")
    ax_t.set_xlabel("time (s)")
    for ax in (ax_d, ax_t):
        ax.axhline(0.0, color="0.6", lw=0.5)
        ax.grid(alpha=0.3)
    ax_t.legend(loc="upper left", fontsize=8)
    if title:
        fig.suptitle(title)
    fig.savefig(png_path, dpi=110)
    plt.close(fig)
