"""The attempt page's 3-D replay: the needle's track, bone contacts, where it reached the target and
X-ray images from a recording, and the pack's anatomy as compact display meshes (binary glTF).

The thesis's trainer lets a trainee watch the attempt against the ideal afterwards (6.1.5); on the
records server the trainer does it in the browser. The server already replays every upload to score
it (``chainsim.game.server.scoring``); here the stored recording of one attempt is replayed again,
headless with off-screen rendering (EGL), and sampled: the needle's tip and direction over the
attempt's time, where the tip touched bone (a contact, as the procedure counts them; reaching the
target is kept apart as ``reached``, it is no contact), and every X-ray image the C-arm made,
rendered by the simulator's own fluoroscopy renderer (``chainsim.game.render.radiograph``) exactly as
the trainee saw it. Only the attempt the recording saved last is kept (a recording starts at the
session's start, so earlier attempts of that session come before it).

Meshes: each pack entity drawn from a mesh file, in its display copy where the pack has one
(``display`` in ``[meshes.X]``), thinned by vertex clustering when still large, with its material's
colour; written as one GLB (trimesh) so the browser downloads a few hundred kB once per pack version.

Replays run in a process of their own (spawned, like the scorers') and the results are kept per
attempt in memory: a page opened twice replays once.
"""

from __future__ import annotations

import hashlib
import io
import json
import multiprocessing
import os
import threading
import time
from collections import OrderedDict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from chainsim.game.records import provenance
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures.procedure import XrayImage

#: needle samples per simulated second kept in the track (the browser interpolates between them)
SAMPLE_HZ = 20.0
#: at most this many X-ray images per attempt; live fluoroscopy makes 15 a second, so beyond
#: one per LIVE_KEEP_S of a live run the pulses in between are left out
MAX_IMAGES = 48
LIVE_KEEP_S = 1.0
#: a display mesh with more triangles than this is thinned for the browser
MAX_TRIANGLES = 20_000


def replay_track(recording_text: str, pack_root: str, pack_paths: list[str]) -> dict:
    """Replay a recording headless with off-screen rendering; the last saved attempt's track:

    ``{"duration_s", "frames": [[t, tip x y z, direction x y z], ...], "contacts": [{"t", "role",
    "point"}], "reached": {"t", "role", "point"} or None, "images": [{"t", "png" (bytes), "view",
    "azimuth_deg", "elevation_deg"}], "needle_length_mm"}`` with t in seconds of the attempt's own clock;
    contacts are the counted ones (obstacles: bone), the target's touch is `reached`."""

    from chainsim.components.resources import PendingInput, Records  # noqa: PLC0415
    from chainsim.game.packs import pack as packs  # noqa: PLC0415
    from chainsim.game.render.renderer import Renderer  # noqa: PLC0415
    from chainsim.game.server.scoring import _recording_fields  # noqa: PLC0415
    from chainsim.game.trainer.headless import app_for_pack, check_events  # noqa: PLC0415
    from chainsim.game.trainer.inputscript import parse_events  # noqa: PLC0415
    from chainsim.systems.procedures import procedure_of  # noqa: PLC0415

    recording = provenance.decode_recording(recording_text)
    fields = _recording_fields(recording)
    events = parse_events(recording, "recording")
    pack = packs.load(Path(pack_root), pack_paths)
    proc = procedure_of(pack.manifest)
    if proc is None or proc.replay is None:
        raise UserError(f"pack {pack.name}: its procedure has no 3-D replay")
    settings = {"model": fields["model"]} if fields["model"] else {}
    app = app_for_pack(pack, fields["scene"], settings=settings, dt=fields["dt"], render=True, save="replay")
    saves: list[tuple[int, int]] = []  # (attempt number, frame index) at each Save
    frames: list[tuple[int, list[float | None]]] = []  # None: not finite (no tip yet)
    contacts: list[tuple[int, dict]] = []
    reached: list[tuple[int, dict]] = []
    images: list[tuple[int, dict]] = []
    try:
        scene = proc.replay(app)

        def capture(class_name: str, trainee: str, record: dict) -> int:
            saves.append((scene.attempt(), len(frames)))
            return len(saves)

        app.insert_resource(Records(save_attempt=capture, list_attempts=lambda c, t: [], where="replay"))
        check_events(app, events, "recording")
        app.resource(PendingInput).extend(events)
        length = scene.length_mm
        every = max(1, round(1.0 / (SAMPLE_HZ * app.time.dt)))
        image_id = -1
        last_live_t = -1e9
        for step in range(fields["steps"]):
            app.update(app.time.dt)
            with app.active():
                f = scene.frame()
                t = f.t
                if step % every == 0 or not frames:
                    frames.append((f.attempt, [t, *_r(f.tip), *_r(f.direction, 4)]))
                if f.contact is not None:
                    role, point, target = f.contact
                    (reached if target else contacts).append((f.attempt, {"t": t, "role": role, "point": _r(point)}))
                shot = proc.xray(app) if proc.xray is not None else None
                fluoro = app.resource(Renderer)._fluoro if app.get_resource(Renderer) is not None else None
                if shot is not None and fluoro is not None and fluoro.image_id != image_id and fluoro.shown:
                    image_id = fluoro.image_id
                    if shot.live and t - last_live_t < LIVE_KEEP_S:
                        continue
                    last_live_t = t if shot.live else last_live_t
                    rgb = fluoro.image_rgb()
                    if rgb is not None:
                        images.append((f.attempt, _xray(t, rgb, shot)))
    finally:
        app.close()
    if not saves:
        raise UserError("the recording does not replay to a saved attempt")
    attempt, end = saves[-1]
    kept = [f for a, f in frames[: end + 1] if a == attempt]
    return {
        "needle_length_mm": length,
        "duration_s": kept[-1][0] if kept else 0.0,
        "frames": kept,
        "contacts": [c for a, c in contacts if a == attempt],
        "reached": next((c for a, c in reversed(reached) if a == attempt), None),
        "images": [i for a, i in images if a == attempt][-MAX_IMAGES:],
    }


def _xray(t: float, rgb: np.ndarray, shot: XrayImage) -> dict:
    """One X-ray image of the track: when, the picture and the view and pose it was taken from."""
    return {
        "t": t,
        "png": _png(rgb),
        "view": shot.view,
        "live": bool(shot.live),
        "azimuth_deg": round(float(shot.azimuth_deg), 1),
        "elevation_deg": round(float(shot.elevation_deg), 1),
    }


def _r(v, digits: int = 2) -> list[float | None]:
    return [round(float(c), digits) if np.isfinite(c) else None for c in np.asarray(v, float)]


def _png(rgb: np.ndarray) -> bytes:
    from PIL import Image  # noqa: PLC0415

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb), "RGB").save(buf, format="PNG", optimize=True)
    return buf.getvalue()


# -- display meshes ----------------------------------------------------------------------------


def cluster(vertices: np.ndarray, triangles: np.ndarray, most: int) -> tuple[np.ndarray, np.ndarray]:
    """A mesh thinned to about `most` triangles by vertex clustering: vertices snapped to a grid (the
    cell grown until few enough triangles are left), each cell's vertices merged at their mean,
    triangles that collapse dropped. Coarse but shape-true to within a cell, which is all a
    see-through overview needs."""
    v = np.asarray(vertices, float)
    f = np.asarray(triangles, np.int64)
    if len(f) <= most:
        return v, f
    lo, hi = v.min(axis=0), v.max(axis=0)
    cell = float(np.max(hi - lo)) / 400.0
    while True:
        keys = np.floor((v - lo) / cell).astype(np.int64)
        _, inverse = np.unique(keys, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        g = inverse[f]
        keep = (g[:, 0] != g[:, 1]) & (g[:, 1] != g[:, 2]) & (g[:, 0] != g[:, 2])
        if keep.sum() <= most:
            break
        cell *= 1.25
    n = int(inverse.max()) + 1
    sums = np.zeros((n, 3))
    np.add.at(sums, inverse, v)
    counts = np.bincount(inverse, minlength=n)[:, None]
    g = np.unique(np.sort(g[keep], axis=1), axis=0, return_index=True)[1]
    faces = inverse[f][keep][np.sort(g)]
    return sums / counts, faces


def display_glb(pack_root: str, pack_paths: list[str]) -> bytes:
    """The pack's anatomy for the browser: one node per entity drawn from a mesh file (its display copy
    where it has one), named after the entity, coloured by its material; instruments (primitives) are
    left out: the page draws the needle from the track."""
    import trimesh  # noqa: PLC0415

    from chainsim.game.packs import pack as packs  # noqa: PLC0415

    pack = packs.load(Path(pack_root), pack_paths)
    meshes = pack.section("meshes")
    materials = pack.section("materials")
    scene = trimesh.Scene()
    for name, ent in pack.manifest.get("entities", {}).items():
        ref = ent.get("mesh") if isinstance(ent, dict) else None
        if not isinstance(ref, dict) or not ref.get("mesh"):
            continue
        spec = meshes.get(ref["mesh"], {})
        if spec.get("primitive") or not spec.get("path"):
            continue
        md = pack.display_mesh(ref["mesh"])
        v, f = cluster(md.vertices, md.triangles, MAX_TRIANGLES)
        color = list(materials.get(ref.get("material", ""), {}).get("color", [0.8, 0.8, 0.8, 1.0]))[:4]
        rgba = np.clip(np.array((color + [1.0])[:4]) * 255, 0, 255).astype(np.uint8)
        mesh = trimesh.Trimesh(vertices=v.astype(np.float32), faces=f.astype(np.uint32), process=False)
        # one colour per mesh as its material: no per-vertex or per-face colour data to download
        material = trimesh.visual.material.PBRMaterial(name=name, baseColorFactor=rgba, metallicFactor=0.0)
        mesh.visual = trimesh.visual.TextureVisuals(material=material)
        scene.add_geometry(mesh, node_name=name, geom_name=name)
    return scene.export(file_type="glb")


# -- the server's side: one replay process, results kept ----------------------------------------


def _leave_with(server_pid: int) -> None:
    """In the replay process: exit when the server is gone (a server killed without its shutdown
    would otherwise leave this process, its GL context and its memory behind)."""

    def watch() -> None:
        while os.getppid() == server_pid:
            time.sleep(2.0)
        os._exit(0)

    threading.Thread(target=watch, name="leave-with-server", daemon=True).start()


class Replays:
    """Replays and meshes for the attempt pages, computed in one spawned process and kept in memory."""

    def __init__(self, keep: int = 16) -> None:
        self.keep = keep
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()
        self._tracks: OrderedDict[str, dict] = OrderedDict()
        self._glbs: dict[str, bytes] = {}

    def _submit(self, fn, *args) -> Any:
        with self._lock:
            if self._pool is None:
                self._pool = ProcessPoolExecutor(
                    1, mp_context=multiprocessing.get_context("spawn"), initializer=_leave_with, initargs=(os.getpid(),)
                )
            pool = self._pool
        return pool.submit(fn, *args).result()

    def track(self, key: str, recording: str, pack_root: str, pack_paths: list[str]) -> dict:
        with self._lock:
            hit = self._tracks.get(key)
            if hit is not None:
                self._tracks.move_to_end(key)
                return hit
        track = self._submit(replay_track, recording, pack_root, list(pack_paths))
        with self._lock:
            self._tracks[key] = track
            while len(self._tracks) > self.keep:
                self._tracks.popitem(last=False)
        return track

    def glb(self, key: str, pack_root: str, pack_paths: list[str]) -> bytes:
        hit = self._glbs.get(key)
        if hit is None:
            hit = self._glbs[key] = self._submit(display_glb, pack_root, list(pack_paths))
        return hit

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)


def track_key(recording: str, pack_hash: str) -> str:
    """What a replay's result depends on: the recording and the pack's version."""
    return hashlib.sha256(json.dumps([recording, pack_hash]).encode()).hexdigest()[:32]


def public_track(track: dict, attempt_id: int) -> dict:
    """The track as the page reads it: images as addresses instead of bytes."""
    out = {k: v for k, v in track.items() if k != "images"}
    out["images"] = [
        {**{k: v for k, v in im.items() if k != "png"}, "url": f"/attempts/{attempt_id}/xray/{k + 1}.png"}
        for k, im in enumerate(track["images"])
    ]
    return out
