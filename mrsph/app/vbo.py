"""GGUI's vertex buffers, packed with numpy and handed to GGUI as host memory.

``ti.ui``'s canvas and scene calls take Taichi fields and copy each into a vertex buffer
with a kernel compiled for that field: a new field (a first frame, a buffer that grew,
the first 3D scene after a 2D one) compiles again, 50-90 ms a field, 1.2 s of the
window's first frame of demo_2d. GGUI takes a numpy array as the vertex buffer too
(``FieldSource.HostMappedPtr``: it copies the memory during the call), so the renderer
packs the buffer itself: no Taichi kernel, nothing to compile, and exactly as many
vertices as are drawn (no unused slots to park outside the view).

The layout is GGUI 1.7.4's (``taichi/ui/staging_buffer.py``), pinned with taichi in
requirements.txt: 12 float32 a vertex, the position at 0:3, the normal at 3:6 (a
circle's or particle's radius at 3), texture coordinates at 6:8, RGBA at 8:12.
"""

from __future__ import annotations

import numpy as np
from taichi.ui.utils import get_field_info

STRIDE = 12
_NONE = get_field_info(None)  # "no index buffer"


def pack(x, normal=None, radius=None, colour=None) -> np.ndarray:
    """An (n, 12) float32 vertex buffer of positions ``x`` (n, 2 or 3), with optional
    normals (n, 3), radii (n,) and RGB colours (n, 3)."""
    x = np.asarray(x, dtype=np.float32)
    out = np.zeros((len(x), STRIDE), dtype=np.float32)
    out[:, : x.shape[1]] = x
    if normal is not None:
        out[:, 3:6] = normal
    if radius is not None:
        out[:, 3] = radius
    if colour is not None:
        out[:, 8:11] = colour
    out[:, 11] = 1.0
    return out


class Vertices:
    """The GGUI calls of one frame, each given a packed buffer; the buffers are kept
    until the next frame (GGUI reads host memory during the call, but nothing should
    rely on that for a frame it has not drawn yet)."""

    def __init__(self):
        self._held: list = []

    def new_frame(self) -> None:
        self._held = []

    def _info(self, vbo: np.ndarray):
        vbo = np.ascontiguousarray(vbo, dtype=np.float32)
        self._held.append(vbo)
        return get_field_info(vbo)

    # -- 2D canvas (colour: RGB in [0, 1]; a per-vertex colour in the buffer wins) -----
    def circles(self, canvas, vbo, per_colour: bool, per_radius: bool, colour=(0.5, 0.5, 0.5), radius=0.0) -> None:
        if len(vbo):
            canvas.canvas.circles(self._info(vbo), per_colour, per_radius, tuple(colour), float(radius))

    def triangles(self, canvas, vbo, per_colour: bool, colour=(0.5, 0.5, 0.5)) -> None:
        if len(vbo):
            canvas.canvas.triangles(self._info(vbo), _NONE, per_colour, tuple(colour))

    def lines(self, canvas, vbo, width: float, per_colour: bool, colour=(0.5, 0.5, 0.5)) -> None:
        if len(vbo) >= 2:
            canvas.canvas.lines(self._info(vbo[: len(vbo) // 2 * 2]), _NONE, per_colour, tuple(colour), float(width))

    # -- 3D scene ------------------------------------------------------------------------
    def particles(self, scene, vbo, per_colour: bool, per_radius: bool, colour=(0.5, 0.5, 0.5), radius=0.0) -> None:
        if len(vbo):
            scene.scene.particles(self._info(vbo), per_colour, per_radius, tuple(colour), float(radius), len(vbo), 0)

    def mesh(self, scene, vbo, per_colour: bool, colour=(0.5, 0.5, 0.5), two_sided: bool = True) -> None:
        if len(vbo):
            n = len(vbo)
            scene.scene.mesh(self._info(vbo), per_colour, _NONE, tuple(colour), two_sided, n, 0, n, 0, False)

    def scene_lines(self, scene, vbo, width: float, per_colour: bool, colour=(0.5, 0.5, 0.5)) -> None:
        n = len(vbo) // 2 * 2
        if n:
            scene.scene.lines(self._info(vbo[:n]), _NONE, per_colour, tuple(colour), float(width), n, 0, n, 0)
