"""Viewports and cameras without GL: layout fractions -> pixel rectangles, view/projection matrices,
world point -> pixel and pixel -> ray (thesis 3.3.4: the linked global, needle-tip and controller views).

Conventions (all matrices are 4 x 4 numpy float64, column vectors, OpenGL clip space):

* Window pixels have their origin at the bottom-left (pyglet and the input events). A pixel with
  integer index (i, j) covers [i, i+1) x [j, j+1); its centre is (i + 0.5, j + 0.5). `Camera.ray`
  takes continuous window coordinates, so pass a pixel centre to hit what the renderer shows there.
* The world is Z-up, millimetres.
* Orbit / fixed camera: the eye sits `distance` from `target`. With yaw = pitch = 0 the eye is on the
  +Y side of the target and looks along -Y; yaw turns the eye counter-clockwise about +Z (seen from
  above), pitch raises it (positive pitch looks down on the target).
* `fit_orbit` places an orbit/fixed camera so a box fills a viewport with every corner inside it.
* Attached camera: the eye is at the entity's origin plus `offset` (given in the entity's local frame,
  scaled and rotated with it) and looks along the entity's rotated local +Z axis, with the rotated
  local +Y axis as the up hint. A needle whose tip is at its entity origin pointing along local +Z
  therefore sees what lies ahead of the tip. Attached cameras ignore mouse input.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from chainsim.systems.engine import quaternion

KINDS_3D = ("orbit", "attached", "fixed")


@dataclass(frozen=True, slots=True)
class Rect:
    """A pixel rectangle, origin bottom-left."""

    x: int
    y: int
    w: int
    h: int

    def contains(self, px: float, py: float) -> bool:
        return self.x <= px < self.x + self.w and self.y <= py < self.y + self.h

    @property
    def aspect(self) -> float:
        return self.w / self.h if self.h > 0 else 1.0

    def scaled(self, sx: float, sy: float | None = None) -> Rect:
        """The same rectangle in another pixel grid (framebuffer vs window size on HiDPI screens)."""
        sy = sx if sy is None else sy
        x0, y0 = round(self.x * sx), round(self.y * sy)
        return Rect(x0, y0, round((self.x + self.w) * sx) - x0, round((self.y + self.h) * sy) - y0)


def fraction_rect(frac, width: int, height: int) -> Rect:
    """[x, y, w, h] window fractions -> pixels. Edges are rounded, so neighbouring viewports share
    their boundary pixel-exactly and tile the window without gaps or overlaps."""
    fx, fy, fw, fh = (float(v) for v in frac)
    x0, y0 = round(fx * width), round(fy * height)
    x1, y1 = round((fx + fw) * width), round((fy + fh) * height)
    return Rect(x0, y0, max(x1 - x0, 0), max(y1 - y0, 0))


def layout_rects(viewports: list[dict], width: int, height: int) -> dict[str, Rect]:
    """Pixel rectangle of every viewport table of a layout."""
    return {vp["name"]: fraction_rect(vp["rect"], width, height) for vp in viewports}


# -- matrices ------------------------------------------------------------------------------------


def look_at(eye, target, up) -> np.ndarray:
    eye = np.asarray(eye, float)
    f = np.asarray(target, float) - eye
    f /= np.linalg.norm(f)
    up = np.asarray(up, float)
    s = np.cross(f, up)
    if np.linalg.norm(s) < 1e-9:  # looking straight along the up hint: pick another
        alt = np.array([0.0, 1.0, 0.0]) if abs(f[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
        s = np.cross(f, alt)
    s /= np.linalg.norm(s)
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def perspective(fov_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    f = 1.0 / math.tan(math.radians(fov_deg) / 2.0)
    m = np.zeros((4, 4))
    m[0, 0] = f / aspect
    m[1, 1] = f
    m[2, 2] = (far + near) / (near - far)
    m[2, 3] = 2.0 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


# -- cameras -------------------------------------------------------------------------------------


@dataclass(slots=True)
class Camera:
    """A perspective camera: eye, target, up hint; see the module docstring for conventions."""

    eye: np.ndarray = field(default_factory=lambda: np.array([0.0, 400.0, 0.0]))
    target: np.ndarray = field(default_factory=lambda: np.zeros(3))
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    fov: float = 40.0
    near: float = 1.0
    far: float = 5000.0

    def view(self) -> np.ndarray:
        return look_at(self.eye, self.target, self.up)

    def projection(self, aspect: float) -> np.ndarray:
        return perspective(self.fov, aspect, self.near, self.far)

    def view_projection(self, aspect: float) -> np.ndarray:
        return self.projection(aspect) @ self.view()

    def project(self, points, rect: Rect) -> np.ndarray:
        """World points (K, 3) -> (K, 3): window x, y (continuous pixels) and NDC depth in [-1, 1]."""
        p = np.atleast_2d(np.asarray(points, float))
        clip = np.c_[p, np.ones(len(p))] @ self.view_projection(rect.aspect).T
        with np.errstate(divide="ignore", invalid="ignore"):  # points in the eye's plane: inf/nan, never drawn
            ndc = clip[:, :3] / clip[:, 3:4]
        x = rect.x + (ndc[:, 0] + 1.0) * 0.5 * rect.w
        y = rect.y + (ndc[:, 1] + 1.0) * 0.5 * rect.h
        return np.c_[x, y, ndc[:, 2]]

    def ray(self, px: float, py: float, rect: Rect) -> tuple[np.ndarray, np.ndarray]:
        """Continuous window coordinates -> (origin on the near plane, unit direction), world mm."""
        nx = 2.0 * (px - rect.x) / rect.w - 1.0
        ny = 2.0 * (py - rect.y) / rect.h - 1.0
        inv = np.linalg.inv(self.view_projection(rect.aspect))
        a = inv @ np.array([nx, ny, -1.0, 1.0])
        b = inv @ np.array([nx, ny, 1.0, 1.0])
        a = a[:3] / a[3]
        b = b[:3] / b[3]
        d = b - a
        return a, d / np.linalg.norm(d)

    @property
    def forward(self) -> np.ndarray:
        f = np.asarray(self.target, float) - np.asarray(self.eye, float)
        return f / np.linalg.norm(f)


@dataclass(slots=True)
class OrbitCamera(Camera):
    """Spherical camera around `target`; rotate / zoom / pan from mouse input."""

    distance: float = 400.0
    yaw: float = 0.0  # degrees
    pitch: float = 0.0  # degrees, clamped to (-89.9, 89.9)

    def __post_init__(self) -> None:
        self.target = np.asarray(self.target, float).copy()
        self.update_eye()

    def update_eye(self) -> None:
        cy, sy = math.cos(math.radians(self.yaw)), math.sin(math.radians(self.yaw))
        cp, sp = math.cos(math.radians(self.pitch)), math.sin(math.radians(self.pitch))
        self.eye = self.target + self.distance * np.array([-sy * cp, cy * cp, sp])
        self.up = np.array([0.0, 0.0, 1.0])

    def rotate(self, dx: float, dy: float, deg_per_px: float = 0.4) -> None:
        """Drag right turns the scene to the right (the eye moves left); drag up tilts it towards the viewer."""
        self.yaw = (self.yaw - dx * deg_per_px) % 360.0
        self.pitch = float(np.clip(self.pitch - dy * deg_per_px, -89.9, 89.9))
        self.update_eye()

    def zoom(self, steps: float, factor: float = 0.9) -> None:
        """Scroll up (positive) moves the eye closer."""
        steps = float(np.clip(steps, -1000.0, 1000.0))  # beyond this the clip below decides anyway; no overflow
        self.distance = float(np.clip(self.distance * factor**steps, max(self.near * 2, 1e-3), self.far * 0.9))
        self.update_eye()

    def pan(self, dx: float, dy: float, rect: Rect) -> None:
        """Move the target so the scene follows the cursor (at the target's depth)."""
        h = 2.0 * self.distance * math.tan(math.radians(self.fov) / 2.0)
        mm_per_px = h / max(rect.h, 1)
        f = self.forward
        right = np.cross(f, self.up)
        right /= np.linalg.norm(right)
        up = np.cross(right, f)
        self.target = self.target - (right * dx + up * dy) * mm_per_px
        self.update_eye()


def box_corners(lo, hi) -> np.ndarray:
    """The 8 corners of the axis-aligned box lo..hi, (8, 3)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def fit_orbit(cam: OrbitCamera, rect: Rect, lo, hi, margin: float = 12.0, top: float = 0.0) -> None:
    """Move `cam` (keeping its yaw and pitch) so the box lo..hi fills `rect` as far as it can while every
    corner stays inside it: `margin` pixels from each edge and `top` more pixels free along the top
    (where a view draws its caption and step text). Sets the distance and the target.

    Each corner's position relative to the box centre in the camera's frame (x right, y up, z ahead)
    bounds the distance d from below: |x| <= m_x tan(fov_x / 2) (d + z) across; vertically the target
    may also slide by s along the camera's up so the box sits in the free band [y_lo, y_hi] (NDC):
    y - y_hi t (d + z) <= s <= y - y_lo t (d + z). The smallest d with such an s is found by bisection
    (the interval of s widens as d grows)."""
    w, h = max(rect.w, 1), max(rect.h, 1)
    centre = 0.5 * (np.asarray(lo, float) + np.asarray(hi, float))
    cam.target = centre.copy()
    cam.update_eye()
    f = cam.forward
    s_ax = np.cross(f, cam.up)
    if np.linalg.norm(s_ax) < 1e-9:
        s_ax = np.array([1.0, 0.0, 0.0])
    s_ax /= np.linalg.norm(s_ax)
    u_ax = np.cross(s_ax, f)
    rel = box_corners(lo, hi) - centre
    x, y, z = rel @ s_ax, rel @ u_ax, rel @ f
    ty = math.tan(math.radians(cam.fov) / 2.0)
    tx = ty * (w / h)
    xm = max(1.0 - 2.0 * margin / w, 0.1)
    y_hi, y_lo = 1.0 - 2.0 * (margin + top) / h, -1.0 + 2.0 * margin / h
    if y_hi - y_lo < 0.2:  # a view too short for its top band: centre the box in the whole view
        y_hi, y_lo = 0.9, -0.9
    d_min = float(np.max(np.abs(x) / (xm * tx) - z))
    d_min = max(d_min, float(np.max(2.0 * cam.near - z)), 1e-3)

    def slide(d: float) -> tuple[float, float]:
        return float(np.max(y - y_hi * ty * (d + z))), float(np.min(y - y_lo * ty * (d + z)))

    a, b = d_min, d_min
    while slide(b)[0] > slide(b)[1]:
        a, b = b, b * 2.0
    for _ in range(60):
        if slide(a)[0] <= slide(a)[1] or b - a <= 1e-6 * b:
            break
        m = 0.5 * (a + b)
        if slide(m)[0] <= slide(m)[1]:
            b = m
        else:
            a = m
    d = a if slide(a)[0] <= slide(a)[1] else b
    s_lo, s_hi = slide(d)
    cam.target = centre + 0.5 * (s_lo + s_hi) * u_ax
    cam.distance = d
    cam.far = max(cam.far, 4.0 * (d + float(np.max(np.abs(rel)))))
    cam.update_eye()


def orbit_from_table(vp: dict) -> OrbitCamera:
    return OrbitCamera(
        target=np.asarray(vp.get("target", (0, 0, 0)), float),
        fov=float(vp.get("fov", 40.0)),
        near=float(vp.get("near", 1.0)),
        far=float(vp.get("far", 5000.0)),
        distance=float(vp.get("distance", 400.0)),
        yaw=float(vp.get("yaw", 0.0)),
        pitch=float(vp.get("pitch", 0.0)),
    )


def attached_camera(position, rotation, scale: float, offset, fov: float, near: float, far: float) -> Camera:
    """Camera riding on an entity (convention in the module docstring)."""
    r = quaternion.to_matrix(rotation)
    eye = np.asarray(position, float) + r @ (np.asarray(offset, float) * float(scale))
    fwd = r @ np.array([0.0, 0.0, 1.0])
    up = r @ np.array([0.0, 1.0, 0.0])
    return Camera(eye=eye, target=eye + fwd, up=up, fov=fov, near=near, far=far)


def carm_source_direction(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit vector from the C-arm's isocentre to its X-ray source.

    The source's azimuth is measured in the axial plane from the subject's right (+X) toward the face
    (+Y): 0 puts the source on the right (a lateral view, the beam running right to left), 90 in front
    of the face, 180 on the left. Its elevation is the angle below the axial plane: positive puts the
    source under the chin, so the beam runs upward (caudocranial), as in the submental view."""
    a, b = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.cos(b) * math.cos(a), math.cos(b) * math.sin(a), -math.sin(b)])


def carm_camera(
    azimuth_deg: float,
    elevation_deg: float,
    iso,
    source_to_iso_mm: float,
    source_to_detector_mm: float,
    detector_mm: float,
) -> Camera:
    """The perspective camera of a C-arm: the eye at the X-ray source, looking through the isocentre
    at a round detector `detector_mm` across, `source_to_detector_mm` from the source (the view's
    field of view is the cone the detector subtends). The image's up is the direction in which the
    source would rise with the elevation, so it turns smoothly with the arm (the vertex is up in a
    lateral view, the face in a submental one)."""
    s = carm_source_direction(azimuth_deg, elevation_deg)
    a, b = math.radians(azimuth_deg), math.radians(elevation_deg)
    up = np.array([math.sin(b) * math.cos(a), math.sin(b) * math.sin(a), math.cos(b)])
    iso = np.asarray(iso, float)
    eye = iso + source_to_iso_mm * s
    fov = 2.0 * math.degrees(math.atan(0.5 * detector_mm / source_to_detector_mm))
    near = max(source_to_iso_mm - 250.0, 10.0)  # the head lies within 250 mm of the isocentre
    return Camera(eye=eye, target=iso, up=up, fov=fov, near=near, far=source_to_detector_mm + 50.0)
