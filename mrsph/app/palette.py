"""Colours of the app: per level, per kind, and two colormaps (speed, density).

Numpy only, vectorised, shared by the GGUI renderer and the software rasteriser so
that a video and the window look the same.

Level colours follow the Okabe-Ito palette (Okabe & Ito 2008, "Color Universal
Design"), which stays distinguishable under the common colour-vision deficiencies.
Level 0 is the finest level, so it gets the warm bright orange: where the solver
refines is where the eye should go.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Colour modes understood by :func:`colours`, in the order the window cycles them.
COLOR_MODES = ("level", "kind", "speed", "density")

#: Background and scene-furniture colours (RGB in [0, 1]). A dark slate background
#: makes the bright level colours pop and keeps the sky-blue level visible.
BACKGROUND = (0.085, 0.095, 0.115)
DOMAIN_COLOUR = (0.62, 0.66, 0.72)
OBSTACLE_FILL = (0.30, 0.32, 0.36)
OBSTACLE_EDGE = (0.78, 0.80, 0.84)
#: Marks of what acts on the water (geometry.Mark): the mouse's reach white, the scene's
#: stirrers magenta, a hue no level colour (Okabe-Ito) and no colormap comes near.
MARK_COLOURS = {"mouse": (1.0, 1.0, 1.0), "stirrer": (1.0, 0.2, 1.0)}
#: Water view: the water at its surface and deep down (the 2D body is shaded between the
#: two by the depth under its free surface), its lit surface line, and the drops that
#: left it. With the tint (key t) the body takes the particles' colours (level, speed...)
#: instead, shaded the same way, so that the legend's colours are the water's.
WATER_SHALLOW = (0.33, 0.64, 0.90)
WATER_DEEP = (0.05, 0.19, 0.42)
WATER_SPRAY = (0.78, 0.90, 1.0)
WATER_EDGE = (0.86, 0.95, 1.0)
#: The 3D mesh's colour (lit by the scene's light).
WATER_COLOUR = (0.16, 0.42, 0.78)

# Okabe-Ito, reordered so that consecutive levels differ in both hue and lightness.
_LEVEL_HEX = (
    "#E69F00",  # 0 orange (finest: warm, bright)
    "#56B4E9",  # 1 sky blue
    "#009E73",  # 2 bluish green
    "#CC79A7",  # 3 reddish purple
    "#F0E442",  # 4 yellow
    "#0072B2",  # 5 blue
    "#D55E00",  # 6 vermillion
    "#BBBBBB",  # 7 light grey
)


def _hex(h: str) -> tuple[float, float, float]:
    h = h.lstrip("#")
    return tuple(int(h[i : i + 2], 16) / 255.0 for i in (0, 2, 4))


#: (8, 3) float32; level ``l`` uses row ``l % 8``.
LEVEL_COLOURS = np.array([_hex(h) for h in _LEVEL_HEX], dtype=np.float32)

#: Kind codes (docs/ARCHITECTURE.md) -> colour. Transient states get the saturated colours
#: because they are the interesting, short-lived part of a split or merge.
KIND_NAMES = (
    "regular",
    "transient parent",
    "transient child",
    "transient parent+child",
    "virtual child",
    "virtual parent",
)
KIND_COLOURS = np.array(
    [
        _hex("#8FA9C8"),  # 0 regular: calm grey-blue so transients stand out
        _hex("#E69F00"),  # 1 transient parent: orange
        _hex("#56B4E9"),  # 2 transient child: sky blue
        _hex("#CC79A7"),  # 3 both: reddish purple
        _hex("#9A9A9A"),  # 4 virtual child: grey
        _hex("#6E6E6E"),  # 5 virtual parent: dark grey
    ],
    dtype=np.float32,
)

#: Virtual particles are drawn as a washed-out version of their colour: mix with
#: this grey by VIRTUAL_MIX. They are bookkeeping, not fluid, and must not be mistaken
#: for it even when shown.
VIRTUAL_GREY = np.array((0.72, 0.72, 0.74), dtype=np.float32)
VIRTUAL_MIX = 0.6

# Sequential map for speed: dark blue -> teal -> yellow -> near white. Dark end is
# still well above the background so slow fluid does not vanish.
_SPEED_STOPS = np.array(
    [
        (0.22, 0.34, 0.72),
        (0.10, 0.50, 0.72),
        (0.25, 0.74, 0.66),
        (0.93, 0.86, 0.35),
        (1.00, 0.97, 0.86),
    ],
    dtype=np.float32,
)
# Diverging map for density ratio rho / rho0: blue (too light) -> grey (at rest
# density) -> red (compressed). Symmetric around 1 so compression errors read directly.
_DENSITY_STOPS = np.array(
    [
        (0.13, 0.40, 0.80),
        (0.45, 0.66, 0.90),
        (0.80, 0.80, 0.80),
        (0.95, 0.60, 0.38),
        (0.80, 0.18, 0.12),
    ],
    dtype=np.float32,
)
#: Half-width of the density-ratio range shown: [1 - w, 1 + w]. Weakly compressible
#: SPH targets ~1 % density error; 5 % makes both good and bad runs readable.
DENSITY_RATIO_HALF_RANGE = 0.05

#: Gravity used only to pick a stable speed scale for the colormap when the caller
#: gives none (the snapshot does not carry gravity).
_G_FOR_SPEED_SCALE = 9.81


#: 2D particles are drawn as discs of this many times their radius (half their level's
#: spacing): 0.8 of the spacing, more than the 1/sqrt(2) that covers a square lattice,
#: so that the fluid reads as one body at every level, a split's children (a quarter of
#: their parent's spacing from its centre) cover their parent's square, and the coarse
#: particles a stir has moved off their lattice leave hardly a hole (demo_2d at 1280x720,
#: stirred: 30 background pixels of 139 200 in the water at 1/sqrt(2), 1-30 at 0.8; at
#: 0.5, touching discs, a square lattice leaves 1 - pi/4 = 21 % of it uncovered).
DISC_SCALE = 1.6
#: Shown (``v``), a virtual particle is drawn over the real ones at this share of its
#: size: it sits on real matter of another level (a coarse particle's virtual children,
#: a fine group's virtual parent), so drawn under it, at full size, it showed only at the
#: surface; smaller and on top, both levels show.
VIRTUAL_SCALE = 0.5


@dataclass(frozen=True)
class Style:
    """Scene-level look from the ``[render]`` table: background colour and the scale of
    drawn particle radii (1 = touching discs at the lattice spacing)."""

    background: tuple = BACKGROUND
    point_scale: float = 1.0

    @classmethod
    def from_scene(cls, scene) -> Style:
        from .view import scene_setting

        bg = scene_setting(scene, "render.background", None)
        return cls(
            tuple(float(c) for c in bg) if bg is not None else BACKGROUND,
            float(scene_setting(scene, "render.point_scale")),
        )


def level_colour(level: int) -> np.ndarray:
    """RGB float32 (3,) of a level (wraps around after 8 levels)."""
    return LEVEL_COLOURS[int(level) % len(LEVEL_COLOURS)]


def _ramp(t: np.ndarray, stops: np.ndarray) -> np.ndarray:
    """Piecewise-linear colormap: t in [0, 1] (clipped) -> (N, 3) float32."""
    t = np.clip(np.asarray(t, dtype=np.float32), 0.0, 1.0)
    s = t * (len(stops) - 1)
    i = np.minimum(s.astype(np.int64), len(stops) - 2)
    f = (s - i)[:, None]
    return (stops[i] * (1.0 - f) + stops[i + 1] * f).astype(np.float32)


def speed_colormap(t: np.ndarray) -> np.ndarray:
    """Sequential colormap for normalised speed ``t`` in [0, 1] -> (N, 3) float32."""
    return _ramp(t, _SPEED_STOPS)


def density_colormap(t: np.ndarray) -> np.ndarray:
    """Diverging colormap, ``t`` = 0.5 is rest density -> (N, 3) float32."""
    return _ramp(t, _DENSITY_STOPS)


def default_speed_scale(domain_min, domain_max) -> float:
    """Speed shown as the top of the colormap: sqrt(2 g H) of the domain height H.

    That is the free-fall speed over the whole domain (a dam break never exceeds it by
    much), and it is the same every frame, so videos do not flicker the way per-frame
    auto-scaling would.
    """
    ext = np.asarray(domain_max, dtype=np.float64) - np.asarray(domain_min, dtype=np.float64)
    height = float(ext[1]) if ext.size > 1 else float(ext[0])
    return max(float(np.sqrt(2.0 * _G_FOR_SPEED_SCALE * max(height, 1e-6))), 1e-6)


def is_virtual(kind: np.ndarray) -> np.ndarray:
    """Kind codes 4 and 5 are virtual (docs/ARCHITECTURE.md)."""
    return np.asarray(kind) >= 4


def grey_out(rgb: np.ndarray) -> np.ndarray:
    """The washed-out look used for virtual particles."""
    return (rgb * (1.0 - VIRTUAL_MIX) + VIRTUAL_GREY * VIRTUAL_MIX).astype(np.float32)


def colours(
    snapshot, mode: str = "level", *, speed_scale: float | None = None, rest_density: float | None = None
) -> np.ndarray:
    """Per-particle colours of a snapshot: (N, 3) float32 in [0, 1].

    mode: "level" (palette by refinement level), "kind" (kind codes), "speed"
    (|v| / speed_scale, default :func:`default_speed_scale`) or "density"
    (rho / rest_density around 1, default rest density: ``snapshot.rest_density`` when
    present, else the median density of the real particles).
    Virtual particles (kind >= 4) are greyed out in every mode.
    """
    n = len(snapshot.level)
    if mode == "level":
        rgb = LEVEL_COLOURS[np.asarray(snapshot.level, dtype=np.int64) % len(LEVEL_COLOURS)]
    elif mode == "kind":
        kind = np.clip(np.asarray(snapshot.kind, dtype=np.int64), 0, len(KIND_COLOURS) - 1)
        rgb = KIND_COLOURS[kind]
    elif mode == "speed":
        if speed_scale is None:
            speed_scale = default_speed_scale(snapshot.domain_min, snapshot.domain_max)
        speed = np.linalg.norm(np.asarray(snapshot.v, dtype=np.float32).reshape(n, -1), axis=1)
        rgb = speed_colormap(speed / float(speed_scale))
    elif mode == "density":
        rho = np.asarray(snapshot.rho, dtype=np.float32).reshape(n)
        if rest_density is None:
            rest_density = getattr(snapshot, "rest_density", None)
        if rest_density is None:
            real = ~is_virtual(snapshot.kind)
            rest_density = float(np.median(rho[real])) if real.any() else 1.0
        ratio = rho / max(float(rest_density), 1e-12)
        rgb = density_colormap(0.5 + (ratio - 1.0) / (2.0 * DENSITY_RATIO_HALF_RANGE))
    else:
        raise ValueError(f"unknown colour mode {mode!r}; expected one of {COLOR_MODES}")
    rgb = np.array(rgb, dtype=np.float32, copy=True).reshape(n, 3)
    virt = is_virtual(snapshot.kind)
    if virt.any():
        rgb[virt] = grey_out(rgb[virt])
    return rgb


def next_mode(mode: str) -> str:
    """The colour mode after ``mode`` in :data:`COLOR_MODES` (wraps around)."""
    i = COLOR_MODES.index(mode) if mode in COLOR_MODES else -1
    return COLOR_MODES[(i + 1) % len(COLOR_MODES)]


def level_mask(image: np.ndarray, level: int, tolerance: float = 0.12) -> np.ndarray:
    """(H, W) bool: pixels of an (H, W, 3) uint8 image showing the colour of ``level``.

    Compares chromaticity (colour divided by its brightest channel), so shaded 3D
    spheres count as their level colour too; dark pixels (background) never count.
    For checking rendered frames (tests, screenshots) without a reference image.
    """
    rgb = np.asarray(image, dtype=np.float32)[..., :3] / 255.0
    peak = rgb.max(axis=-1)
    chroma = rgb / np.maximum(peak, 1e-6)[..., None]
    ref = level_colour(level)
    ref = ref / ref.max()
    return (peak > 0.25) & (np.abs(chroma - ref).max(axis=-1) < tolerance)


def count_level_pixels(image: np.ndarray, levels: int, tolerance: float = 0.12) -> list[int]:
    """Pixel count of each level colour in an image (see :func:`level_mask`)."""
    return [int(level_mask(image, lvl, tolerance).sum()) for lvl in range(int(levels))]
