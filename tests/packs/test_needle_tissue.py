"""The needle meets the tissue in both needle packs: tenting, a puncture per layer at the depth the layer's
data predicts, drag, forces, the trace file and its replay, and the extremes.

References written apart from the code under test: the layer boundaries along the path are found here by
locating points in the shipped tetrahedral meshes (barycentric containment); the stiffness is Boussinesq's
flat-punch formula; the friction is Okamura et al.'s Karnopp form, written out again below.
"""

from __future__ import annotations

import csv
from pathlib import Path

import meshio
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as hs
from needle_insertion import ASSETS, CASES, anatomy, insertion_script, manifest

from chainsim.game.trainer.headless import run_pack
from chainsim.systems.engine import needle_force


def run_script(tmp_path: Path, pack: str | Path, script: str, steps: int, name: str = "run") -> tuple[dict, list]:
    out = tmp_path / name
    sp = tmp_path / f"{name}.toml"
    sp.write_text(script)
    summary = run_pack(str(pack if isinstance(pack, Path) else ASSETS / pack), script=str(sp), out=str(out),
                       steps=steps, save="test")  # fmt: skip
    with open(out / "needle_trace.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return summary, rows


def boundaries_along(pack: str, mesh_file: str, path: str) -> tuple[list[tuple[float, int]], float]:
    """(depth, layer entered) where the layer changes along the path, and the depth where the path leaves the
    tissue, by locating sample points in the mesh."""
    m = meshio.read(ASSETS / pack / "meshes" / mesh_file)
    pts = m.points
    tets = m.cells_dict["tetra"]
    layer = np.concatenate([b for c, b in zip(m.cells, m.cell_data["layer"]) if c.type == "tetra"])
    p = anatomy(pack)["paths"][path]
    e, t = np.array(p["entry"]), np.array(p["target"])
    d = (t - e) / np.linalg.norm(t - e)
    # a hair off the column line so no sample sits on a face shared by two tetrahedra
    off = np.cross(d, [0.0, 0.0, 1.0])
    off = 1e-3 * off / np.linalg.norm(off)
    a, b, c, q = (pts[tets[:, i]] for i in range(4))
    T = np.stack([b - a, c - a, q - a], axis=2)
    Tinv = np.linalg.inv(T)
    out = []
    last = 0
    leave = np.inf
    for s in np.arange(-1.0, np.linalg.norm(t - e) + 5.0, 0.01):
        x = e + s * d + off
        lam = np.einsum("tij,tj->ti", Tinv, x - a)
        inside = np.all(lam >= 0, axis=1) & (lam.sum(axis=1) <= 1)
        here = int(layer[inside][0]) if inside.any() else 0
        if here != last:
            if here > 0:
                out.append((s, here))
            else:
                leave = s
            last = here
    return out, leave


def events(rows: list) -> list[tuple[float, str]]:
    out = []
    for r in rows:
        for e in filter(None, r["event"].split(";")):
            out.append((float(r["tip_depth_mm"]), e))
    return out


# -- the force model against its formulas -----------------------------------------------------------------


def test_punch_stiffness_is_boussinesq_flat_punch():
    # F = 2 a E* delta with E* = E / (1 - nu^2): a 2 mm punch on 40 kPa, nu 0.45
    assert needle_force.punch_stiffness(40.0, 0.45, 2.0) == pytest.approx(2 * 2.0 * 0.040 / (1 - 0.45**2))


@settings(max_examples=200, deadline=None)
@given(
    tent=hs.floats(0, 30), k=hs.floats(0, 2), room=hs.one_of(hs.just(np.inf), hs.floats(0.1, 80)),
    cutting=hs.floats(0, 3), advancing=hs.booleans(),
    lengths=hs.lists(hs.floats(0, 60), min_size=1, max_size=5), v=hs.floats(-200, 200),
    stick=hs.floats(-5, 5), dv=hs.floats(0, 2), data=hs.data(),
)  # fmt: skip
def test_axial_force_terms_match_okamura_form(tent, k, room, cutting, advancing, lengths, v, stick, dv, data):
    n = len(lengths)
    coeff = hs.lists(hs.floats(0, 0.05), min_size=n, max_size=n)
    dyn, visc, static = np.array(data.draw(coeff)), np.array(data.draw(coeff)) * 1e-2, np.array(data.draw(coeff))
    L = np.array(lengths)
    total, f_s, f_c, f_f = needle_force.evaluate(tent, k, room, advancing, cutting, L, dyn, visc, static, v, dv, stick)
    # a press k * tent, stiffening as it closes the room behind the boundary (infinite once it is closed)
    if tent >= room:
        assert f_s == np.inf
        return
    assert f_s == pytest.approx(k * tent if room == np.inf else k * tent * room / (room - tent))
    assert f_c == (cutting if advancing else 0.0)
    if abs(v) > dv:  # sliding: (C + b|v|) per mm, signed with the motion
        want = float(np.sum(L * (dyn + visc * abs(v)))) * np.sign(v)
    else:  # sticking: the tissue's pull, at most the static friction of the inserted length
        cap = float(np.sum(L * static))
        want = min(max(stick, -cap), cap)
    assert f_f == pytest.approx(want, abs=1e-12)
    assert total == pytest.approx(f_s + f_c + f_f, abs=1e-12)


# -- a straight insertion along each pack's textbook path ---------------------------------------------------


@pytest.fixture(scope="module", params=sorted(CASES))
def insertion(request, tmp_path_factory):
    pack = request.param
    path, mesh_file, depth = CASES[pack]
    speed = manifest(pack)["entities"]["needle"]["needle"]["insert_speed"]
    end = 3.0 + depth / speed + 1.0
    back = [(end, 0.0)]
    tmp = tmp_path_factory.mktemp(pack)
    dt = manifest(pack)["settings"]["dt"]
    summary, rows = run_script(tmp, pack, insertion_script(pack, path, depth, back), int((end + 2.0) / dt))
    return pack, path, mesh_file, rows, summary


def test_punctures_come_in_layer_order_at_the_depths_the_layer_data_predicts(insertion):
    pack, path, mesh_file, rows, _ = insertion
    man = manifest(pack)
    layers = {v["mesh_layer"]: (k, v) for k, v in man["tissue_layers"].items()}
    radius = man["needle_tissue"]["contact_radius_mm"]
    speed = man["entities"]["needle"]["needle"]["insert_speed"]
    frame = speed * man["settings"]["dt"]
    depth = CASES[pack][2]
    predicted = []
    crossings, leave = boundaries_along(pack, mesh_file, path)
    for s, number in crossings:
        name, spec = layers[number]
        k = 2 * radius * spec["E_kPa"] * 1e-3 / (1 - spec["nu"] ** 2)
        # F = k t h / (h - t) = F_p  =>  t = F_p h / (k h + F_p), h the tissue behind the boundary
        h, f = leave - max(s, 0.0), spec["puncture_N"]
        pop = max(s, 0.0) + (f * h / (k * h + f) if np.isfinite(h) else f / k)
        # a layer pressed past its threshold in the frame the one above gives way goes too
        if predicted and pop < predicted[-1][0]:
            pop = predicted[-1][0]
        if pop < depth:
            predicted.append((pop, name))
    seen = [(d, e.split(":")[1]) for d, e in events(rows) if e.startswith("puncture:")]
    assert [n for _, n in seen] == [n for _, n in predicted]
    assert len(seen) >= 3  # skin, the tissue under it and muscle at least
    for (d_seen, _), (d_pred, _) in zip(seen, predicted):
        assert d_seen == pytest.approx(d_pred, abs=frame + 0.05)
    assert events(rows)[0][1] == "contact"


def test_force_rises_drops_at_the_pop_grows_with_depth_and_turns_on_withdrawal(insertion):
    pack, _, _, rows, _ = insertion
    depth = np.array([float(r["tip_depth_mm"]) for r in rows])
    axial = np.array([float(r["axial_N"]) for r in rows])
    ev = [r["event"] for r in rows]
    pop = next(i for i, e in enumerate(ev) if "puncture:skin" in e)
    start = next(i for i, e in enumerate(ev) if "contact" in e)
    before = axial[start:pop]
    assert np.all(np.diff(before) > 0)  # the skin tents: stiffness grows with the press
    skin = manifest(pack)["tissue_layers"]["skin"]["puncture_N"]
    # it gives at its threshold: within the frame after the last press below it (a frame's rise, stiffening)
    assert before[-1] < skin <= before[-1] + 1.5 * (before[-1] - before[-2])
    assert axial[pop] < before[-1]  # the drop at the pop
    # deeper, at constant speed: the friction of the inserted length grows with it
    moving = [i for i in range(pop + 5, len(rows)) if depth[i] > depth[i - 1] and not ev[i] and ev[i - 1] == ""]
    assert len(moving) > 5
    assert axial[moving[-1]] > axial[moving[0]]
    # withdrawing, the shaft's friction pulls the other way
    out = [i for i in range(1, len(rows)) if depth[i] < depth[i - 1] - 1e-9 and depth[i] > 1.0]
    assert out and all(axial[i] < 0 for i in out)


def test_the_tissue_is_dragged_in_and_back_and_the_skin_tents_under_the_tip(insertion):
    _, _, _, rows, summary = insertion
    tent = np.array([float(r["skin_tent_mm"]) for r in rows])
    assert tent.max() > 3.0  # the skin followed the tip before it gave
    a = summary["assessment"]
    assert a["punctures"]["skin"] == 1 and a["repunctures"] == 0
    assert a["peak_axial_N"] >= manifest(summary["pack"])["tissue_layers"]["skin"]["puncture_N"] - 1e-6
    assert a["metrics"]["skin_punctures"] == 1.0
    # out of the skin at the end: nothing held, the trace's last row reads no force and no layer
    last = rows[-1]
    assert float(last["tip_depth_mm"]) == 0.0 and last["layer"] == "" and abs(float(last["axial_N"])) < 1e-9


def test_trace_columns_and_one_row_per_frame(insertion):
    pack, _, _, rows, summary = insertion
    assert list(rows[0])[:7] == ["time_s", "tip_depth_mm", "axial_N", "lateral_N", "layer", "event", "skin_tent_mm"]
    # and the axial force's terms, which add up to it
    for r in rows:
        terms = float(r["stiffness_N"]) + float(r["cutting_N"]) + float(r["friction_N"])
        assert terms == pytest.approx(float(r["axial_N"]), abs=2e-5)
    assert len(rows) == summary["steps"]
    layers = set(manifest(pack)["tissue_layers"])
    assert {r["layer"] for r in rows} <= layers | {""}
    assert all(np.isfinite(float(r[k])) for r in rows for k in ("axial_N", "lateral_N", "skin_tent_mm"))


def test_replaying_the_recording_writes_the_same_trace(tmp_path, cli):
    script = tmp_path / "s.toml"
    script.write_text(insertion_script("prp", "left", 25.0, [(4.5, 10.0), (5.5, 30.0)]))
    rec, first, second = tmp_path / "a.json", tmp_path / "first", tmp_path / "second"
    code, _, err = cli("run", "prp", "--headless", "--input", script, "--steps", "800", "--record", rec, "--out", first,
                       "--db", tmp_path / "r.db")  # fmt: skip
    assert code == 0, err
    code, _, err = cli("replay", rec, "--out", second)
    assert code == 0, err
    trace = (first / "needle_trace.csv").read_bytes()
    assert b"puncture:skin" in trace and b"exit:" in trace
    assert trace == (second / "needle_trace.csv").read_bytes()


def analytic_axial(pack: str, crossings: list, leave: float, depth: float, v: float) -> float:
    """Okamura et al.'s force for a tip at `depth` advancing at `v` through the layers met at `crossings`,
    written from the pack's data alone: the press on the first boundary not yet given (a flat punch,
    stiffening as the tissue behind it closes), cutting in the layer the tip is in, and dynamic plus
    viscous friction over the length inserted in each layer."""
    man = manifest(pack)
    layers = {v_["mesh_layer"]: v_ for v_ in man["tissue_layers"].values()}
    radius = man["needle_tissue"]["contact_radius_mm"]
    force, popped = 0.0, []
    for s, number in crossings:
        s = max(s, 0.0)
        spec = layers[number]
        if depth <= s:
            break
        k = 2 * radius * spec["E_kPa"] * 1e-3 / (1 - spec["nu"] ** 2)
        h = leave - s
        t = depth - s
        press = k * t * h / (h - t) if t < h else np.inf
        if press < spec["puncture_N"]:
            force += press
            break
        popped.append((s, spec))
    if popped and force == 0.0 and depth < leave:  # cutting while the tip is in the tissue
        force += popped[-1][1]["cutting_N"]
    for i, (s, spec) in enumerate(popped):
        end = popped[i + 1][0] if i + 1 < len(popped) else depth
        length = min(end, depth, leave) - s
        force += length * (spec["friction_dynamic_N_per_mm"] + spec["friction_viscous_Ns_per_mm2"] * v)
    return force


def test_the_force_depth_curve_follows_okamuras_form(insertion):
    """RMS difference between the simulated axial force and the analytic curve over the insertion at
    constant speed (the frames where a layer gives are where the two can differ by a frame's travel)."""
    pack, path, mesh_file, rows, _ = insertion
    speed = manifest(pack)["entities"]["needle"]["needle"]["insert_speed"]
    crossings, leave = boundaries_along(pack, mesh_file, path)
    depth = np.array([float(r["tip_depth_mm"]) for r in rows])
    sim = np.array([float(r["axial_N"]) for r in rows])
    moving = [i for i in range(1, len(rows)) if depth[i] > depth[i - 1] + 1e-9]
    want = np.array([analytic_axial(pack, crossings, leave, depth[i], speed) for i in moving])
    rmse = float(np.sqrt(np.mean((sim[moving] - want) ** 2)))
    assert rmse < 0.05, rmse
