"""View transforms shared by the GGUI renderer, the software rasteriser and the
mouse mapping: one place decides where a world point lands on screen, so a click
hits the particle under the cursor and a video frames the scene like the window.

Conventions
-----------
* Pixel coordinates ``(px, py)``: x to the right, y *up*, origin at the bottom-left
  corner of the image, in pixels. The canvas coordinates of GGUI are the same divided
  by (width, height). An image row is ``height - 1 - py``.
* World y is up in 2D and 3D.
"""

from __future__ import annotations

import math

import numpy as np

from ..scene.config.schema import default_of

#: Empty border around the domain in 2D, as a fraction of the smaller window side,
#: so the domain outline is not clipped by the window edge.
MARGIN_FRACTION = 0.04
#: Camera speeds of held keys: arrows orbit at this many rad/s; z/x zoom by e^(rate dt)
#: (drags: mrsph.app.pointer).
ORBIT_KEY_RATE = 1.5
ZOOM_KEY_RATE = 1.2


class View2D:
    """Letterboxed map from the world rectangle [domain_min, domain_max] to pixels.

    The scale is the same along x and y (circles stay circles, the domain keeps its
    aspect ratio); the domain is centred and the leftover band stays background.
    """

    def __init__(self, domain_min, domain_max, width: int, height: int, margin: float = MARGIN_FRACTION, region=None):
        """``region``: (x0, y0, x1, y1) pixel rectangle (y up) to fit the domain into,
        default the whole image; the window passes the area left free by its HUD."""
        self.domain_min = np.asarray(domain_min, dtype=np.float64)[:2]
        self.domain_max = np.asarray(domain_max, dtype=np.float64)[:2]
        self.width, self.height = int(width), int(height)
        x0, y0, x1, y1 = region if region is not None else (0, 0, self.width, self.height)
        ext = np.maximum(self.domain_max - self.domain_min, 1e-9)
        pad = margin * min(x1 - x0, y1 - y0)
        #: pixels per metre
        self.scale = float(max(min((x1 - x0 - 2 * pad) / ext[0], (y1 - y0 - 2 * pad) / ext[1]), 1e-9))
        size_px = ext * self.scale
        self.offset = np.array([x0 + x1, y0 + y1], dtype=np.float64) / 2.0 - size_px / 2.0

    def world_to_px(self, x) -> np.ndarray:
        """World (N, 2) -> pixel coordinates (N, 2), y up."""
        x = np.asarray(x, dtype=np.float64)[..., :2]
        return (x - self.domain_min) * self.scale + self.offset

    def px_to_world(self, p) -> np.ndarray:
        p = np.asarray(p, dtype=np.float64)
        return (p - self.offset) / self.scale + self.domain_min

    def world_to_canvas(self, x) -> np.ndarray:
        """World -> GGUI canvas coordinates in [0, 1]^2 (y up)."""
        return self.world_to_px(x) / np.array([self.width, self.height], dtype=np.float64)

    def canvas_to_world(self, u) -> np.ndarray:
        """GGUI canvas / cursor coordinates in [0, 1]^2 (y up) -> world (2,) or (N, 2)."""
        return self.px_to_world(np.asarray(u, dtype=np.float64) * np.array([self.width, self.height]))

    def radius_px(self, r_world) -> np.ndarray:
        return np.asarray(r_world, dtype=np.float64) * self.scale


def fitted_view(domain_min, domain_max, width: int, height: int, region=None, avoid=None) -> View2D:
    """The View2D that fits the domain into ``region`` (x0, y0, x1, y1 pixels, y up;
    default the whole image) and keeps it clear of the box ``avoid`` (same form: the
    legend): where the domain would reach under the box, it is fitted to the right of
    it or below it, whichever draws it larger."""
    full = View2D(domain_min, domain_max, width, height, region=region)
    if avoid is None:
        return full
    x0, y0, x1, y1 = region if region is not None else (0, 0, width, height)
    ax0, ay0, ax1, ay1 = avoid
    lo = full.world_to_px(full.domain_min[None])[0]
    hi = full.world_to_px(full.domain_max[None])[0]
    if lo[0] >= ax1 or hi[0] <= ax0 or lo[1] >= ay1 or hi[1] <= ay0:
        return full  # clear of it already
    options = [(max(ax1, x0), y0, x1, y1), (x0, y0, x1, min(ay0, y1))]
    views = [View2D(domain_min, domain_max, width, height, region=r) for r in options if r[2] > r[0] and r[3] > r[1]]
    return max(views, key=lambda v: v.scale) if views else full


class OrbitCamera:
    """Perspective camera orbiting a target point, y up.

    ``yaw`` turns around the world y axis, ``pitch`` lifts the eye above the target
    plane; the eye sits at ``target + distance * (cos p sin y, sin p, cos p cos y)``.
    ``fov`` is the vertical field of view in degrees, as in GGUI's ``Camera.fov``
    (whose projection is the usual OpenGL perspective with that vertical angle), so
    the software rasteriser and GGUI frame the scene identically.
    """

    PITCH_LIMIT = math.radians(89.0)  # never exactly +-90: the view basis would degenerate

    def __init__(
        self, target=(0.0, 0.0, 0.0), distance: float = 3.0, yaw: float = 0.0, pitch: float = 0.0, fov: float = 45.0
    ):
        self.target = np.asarray(target, dtype=np.float64).copy()
        self.distance = float(distance)
        self.yaw = float(yaw)
        self.pitch = float(pitch)
        self.fov = float(fov)
        self.lateral = 0.0  # sideways shift of the view, in distances (see look_at)
        self.rise = 0.0  # and upward
        self.min_distance = 1e-3
        self.max_distance = 1e6

    # -- construction ----------------------------------------------------------------
    @classmethod
    def from_box(
        cls,
        box_min,
        box_max,
        aspect: float = 16 / 9,
        fov: float = 45.0,
        yaw_deg: float = 35.0,
        pitch_deg: float = 22.0,
        fill: float = 0.92,
    ) -> OrbitCamera:
        """Camera looking at the box centre from a 3/4 view, far enough that the box's
        bounding sphere fits the narrower of the two view angles (times ``fill``)."""
        bmin = np.asarray(box_min, dtype=np.float64)
        bmax = np.asarray(box_max, dtype=np.float64)
        radius = 0.5 * float(np.linalg.norm(bmax - bmin))
        half_v = math.radians(fov) / 2.0
        half_h = math.atan(math.tan(half_v) * aspect)
        half = min(half_v, half_h) * fill
        cam = cls((bmin + bmax) / 2.0, radius / math.sin(half), math.radians(yaw_deg), math.radians(pitch_deg), fov)
        cam.min_distance = radius * 0.05
        cam.max_distance = radius * 50.0
        return cam

    # -- state -----------------------------------------------------------------------
    def _back(self) -> np.ndarray:
        """Unit vector from the target towards the eye (before the sideways shift)."""
        cp = math.cos(self.pitch)
        return np.array([cp * math.sin(self.yaw), math.sin(self.pitch), cp * math.cos(self.yaw)])

    @property
    def position(self) -> np.ndarray:
        """The eye: ``distance`` from the target, shifted sideways by ``lateral``."""
        return self.look_at + self.distance * self._back()

    @property
    def look_at(self) -> np.ndarray:
        """The point the view centre looks at: the target, shifted sideways (along the
        view's right) by ``lateral`` times the distance, and up by ``rise`` times it. The
        target stays the pivot of orbit and zoom, and is seen at lateral / (tan(fov/2)
        aspect) across the image and rise / tan(fov/2) up it (NDC): the window puts it at
        the centre of the area its panels leave free."""
        if self.lateral == 0.0 and self.rise == 0.0:
            return self.target.copy()
        _, right, up = self.basis()
        return self.target - (right * self.lateral + up * self.rise) * self.distance

    def basis(self):
        """(forward, right, up) unit vectors of the view."""
        forward = -self._back()
        right = np.cross(forward, np.array([0.0, 1.0, 0.0]))
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        return forward, right, up

    @property
    def z_near(self) -> float:
        return max(self.distance * 1e-3, 1e-4)

    @property
    def z_far(self) -> float:
        return self.distance * 100.0

    # -- user motion -----------------------------------------------------------------
    def orbit(self, dyaw: float, dpitch: float) -> None:
        self.yaw = (self.yaw + dyaw) % (2.0 * math.pi)
        self.pitch = float(np.clip(self.pitch + dpitch, -self.PITCH_LIMIT, self.PITCH_LIMIT))

    def zoom(self, factor: float) -> None:
        """factor < 1 moves closer."""
        self.distance = float(np.clip(self.distance * factor, self.min_distance, self.max_distance))

    def keys(self, left: float, right: float, up: float, down: float, closer: float, farther: float) -> None:
        """Held keys, each given as the seconds it acted this frame: the arrows orbit,
        closer / farther (z / x) zoom."""
        yaw, pitch = (left - right) * ORBIT_KEY_RATE, (up - down) * ORBIT_KEY_RATE
        if yaw or pitch:
            self.orbit(yaw, pitch)
        if farther != closer:
            self.zoom(math.exp((farther - closer) * ZOOM_KEY_RATE))

    def pan(self, dx: float, dy: float) -> None:
        """Move the target in the view plane; dx, dy in units of the view height at the
        target, so a drag across the whole window moves the scene by one window."""
        _, right, up = self.basis()
        h = 2.0 * self.distance * math.tan(math.radians(self.fov) / 2.0)
        self.target = self.target - right * dx * h - up * dy * h

    # -- projection ------------------------------------------------------------------
    def focal_px(self, height: int) -> float:
        return (height / 2.0) / math.tan(math.radians(self.fov) / 2.0)

    def to_view(self, points) -> np.ndarray:
        """World (N, 3) -> view coordinates (N, 3): (right, up, depth along forward)."""
        forward, right, up = self.basis()
        d = np.asarray(points, dtype=np.float64).reshape(-1, 3) - self.position
        return np.stack([d @ right, d @ up, d @ forward], axis=1)

    def project(self, points, width: int, height: int):
        """World (N, 3) -> (px (N, 2) pixel coords y up, depth (N,)). Points behind the
        camera get depth <= 0 and meaningless pixel coordinates: callers drop them."""
        v = self.to_view(points)
        f = self.focal_px(height)
        z = v[:, 2]
        zsafe = np.where(np.abs(z) < 1e-12, 1e-12, z)
        px = np.empty((len(v), 2))
        px[:, 0] = width / 2.0 + f * v[:, 0] / zsafe
        px[:, 1] = height / 2.0 + f * v[:, 1] / zsafe
        return px, z

    def ray(self, u: float, v: float, aspect: float):
        """Ray through the canvas point (u, v) in [0, 1]^2 (y up): (origin, unit dir)."""
        forward, right, up = self.basis()
        t = math.tan(math.radians(self.fov) / 2.0)
        d = forward + right * (2.0 * u - 1.0) * t * aspect + up * (2.0 * v - 1.0) * t
        return self.position.copy(), d / np.linalg.norm(d)

    def view_matrix(self) -> np.ndarray:
        """4x4 world -> eye matrix (OpenGL convention: camera looks down -z)."""
        forward, right, up = self.basis()
        m = np.eye(4)
        m[0, :3], m[1, :3], m[2, :3] = right, up, -forward
        m[:3, 3] = -m[:3, :3] @ self.position
        return m

    def projection_matrix(self, aspect: float) -> np.ndarray:
        """4x4 OpenGL perspective matrix with vertical fov ``self.fov``."""
        f = 1.0 / math.tan(math.radians(self.fov) / 2.0)
        n, fa = self.z_near, self.z_far
        m = np.zeros((4, 4))
        m[0, 0], m[1, 1] = f / aspect, f
        m[2, 2], m[2, 3] = (fa + n) / (n - fa), 2 * fa * n / (n - fa)
        m[3, 2] = -1.0
        return m


def box_edges(box_min, box_max) -> np.ndarray:
    """The 12 edges of an axis-aligned 3D box as (24, 3) segment end points, or the 4
    edges of a 2D rectangle as (8, 2)."""
    lo = np.asarray(box_min, dtype=np.float64)
    hi = np.asarray(box_max, dtype=np.float64)
    d = len(lo)
    corners = np.array([[hi[k] if (c >> k) & 1 else lo[k] for k in range(d)] for c in range(2**d)])
    segs = []
    for a in range(2**d):
        for k in range(d):
            b = a | (1 << k)
            if b != a:
                segs += [corners[a], corners[b]]
    return np.array(segs)


def circle_loop(center, radius: float, segments: int = 64, axes=(0, 1)) -> np.ndarray:
    """A circle as a closed polyline turned into line segments: (2*segments, dim)."""
    c = np.asarray(center, dtype=np.float64)
    t = np.linspace(0.0, 2.0 * math.pi, segments + 1)
    pts = np.repeat(c[None, :], segments + 1, axis=0)
    pts[:, axes[0]] += radius * np.cos(t)
    pts[:, axes[1]] += radius * np.sin(t)
    return np.stack([pts[:-1], pts[1:]], axis=1).reshape(-1, len(c))


_SCHEMA = object()  # scene_setting's default: the schema's


def scene_setting(scene, dotted: str, default=_SCHEMA):
    """``scene.get(dotted)`` for an ``mrsph.scene.config.Scene``, a nested dict lookup for a
    plain dict, ``default`` when the key or the scene is missing: by default the schema's
    (``schema.default_of``), so that the app writes none of its own. A ``Scene`` holds
    every key resolved; a plain dict (a stand-in's) may lack any, which is never an
    error here."""
    if default is _SCHEMA:
        dim = scene_setting(scene, "dim", 2) if scene is not None and dotted != "dim" else 2
        default = default_of(dotted, int(dim))
    if scene is None:
        return default
    getter = getattr(scene, "get", None)
    if getter is not None and not isinstance(scene, dict):
        try:
            value = getter(dotted)
        except (KeyError, AttributeError, TypeError):
            return default
        return default if value is None else value
    node = scene
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return default
        node = node[part]
    return default if node is None else node


def camera_for_scene(scene, box_min, box_max, aspect: float, fov: float = 45.0) -> OrbitCamera:
    """The initial 3D camera: ``render.camera_position`` / ``render.camera_lookat`` from
    the scene when given, else framed automatically on the domain box."""
    cam = OrbitCamera.from_box(box_min, box_max, aspect, fov=fov)
    pos = scene_setting(scene, "render.camera_position", None)
    look = scene_setting(scene, "render.camera_lookat", None)
    if pos is not None or look is not None:
        target = np.asarray(look if look is not None else cam.target, dtype=np.float64)
        eye = np.asarray(pos if pos is not None else cam.position, dtype=np.float64)
        d = eye - target
        dist = float(np.linalg.norm(d))
        if dist > 1e-9:
            cam.target, cam.distance = target, dist
            cam.yaw = math.atan2(d[0], d[2])
            cam.pitch = float(np.clip(math.asin(d[1] / dist), -cam.PITCH_LIMIT, cam.PITCH_LIMIT))
    return cam


def framed_camera(scene, box_min, box_max, size, viewport=(0.0, 0.0, 1.0, 1.0), avoid=None) -> OrbitCamera:
    """The 3D camera framed within ``viewport`` (x0, y0, x1, y1 fractions of the window,
    y up): on the domain box fitted to it, or from the scene's ``render.camera_position``
    (framed for a whole image) moved back by the viewport's share of the window; its
    target, the pivot of orbit and zoom, seen at the viewport's centre (the projection
    spans the whole window: ``lateral``, ``rise``). Where the box would reach under
    ``avoid`` (x0, y0, x1, y1 pixels, y up: the legend), it is framed below it."""
    cam = _frame(scene, box_min, box_max, size, viewport)
    if avoid is None:
        return cam
    w, h = size
    lo, hi = np.asarray(box_min, np.float64), np.asarray(box_max, np.float64)
    corners = np.array([[hi[k] if (c >> k) & 1 else lo[k] for k in range(3)] for c in range(8)])
    px, depth = cam.project(corners, w, h)
    ax0, ay0, ax1, ay1 = avoid
    if (depth > 0).all() and (px[:, 0].min() >= ax1 or px[:, 1].max() <= ay0):
        return cam  # clear of it already
    x0, y0, x1, _ = viewport
    top = min(viewport[3], ay0 / h)
    return _frame(scene, box_min, box_max, size, (x0, y0, x1, top)) if top > y0 + 0.2 else cam


def _frame(scene, box_min, box_max, size, viewport) -> OrbitCamera:
    w, h = size
    x0, y0, x1, y1 = viewport
    fx, fy = max(x1 - x0, 1e-3), max(y1 - y0, 1e-3)
    fov = OrbitCamera().fov
    # framed for the viewport's height: a vertical angle of its share of the window's
    fov_part = math.degrees(2.0 * math.atan(math.tan(math.radians(fov) / 2.0) * fy))
    cam = camera_for_scene(scene, box_min, box_max, fx * w / max(fy * h, 1.0), fov=fov_part)
    cam.fov = fov
    if scene_setting(scene, "render.camera_position", None) is not None:
        cam.distance /= min(fx, fy)
    tan = math.tan(math.radians(fov) / 2.0)
    cam.lateral = (x0 + x1 - 1.0) * tan * w / h  # the viewport's centre, in [-1, 1] across
    cam.rise = (y0 + y1 - 1.0) * tan
    return cam
