"""The legend: what the colours mean, each entry with its swatch, and the simulated time.

An ImGui panel in the top-left corner holds the text; the swatches are drawn on the
canvas in a strip along the panel's left side, row by row (GGUI 1.7.4's ImGui has no
coloured rectangles, and its font no block glyph). The panel keeps one size for every
colour mode (room for the longest list), so that a mode change moves nothing, and the
renderers fit the scene beside or below it, never under it (``mrsph.app.render``).

In the water view the legend gives the water's colours; with the tint (``t``) the
water takes the colour mode's colours, and the legend gives those.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from . import palette
from .loading import CHAR_PX, LINE_PX, PAD_PX, TITLE_PX

#: Where the panel is: its margin from the window's corner, the swatch strip's width.
MARGIN_PX = 8
SWATCH_STRIP_PX = 22
SWATCH_PX = 11
#: Characters of the longest line, and rows at most: the time and mode, six kinds.
CHARS = 32
MAX_ROWS = 7
#: The strip's background: ImGui's panel colour (its dark style, over the background).
STRIP_COLOUR = (0.065, 0.065, 0.07)


class Entry(NamedTuple):
    text: str
    colour: tuple | None  # None: a line without a swatch (the title)


def _rgb(c) -> tuple:
    return tuple(float(v) for v in np.asarray(c, np.float32).reshape(3))


def entries(snapshot, color_mode: str, surface: bool = False, tint: bool = False) -> list[Entry]:
    """The legend's lines after the time: a title, then each colour with its meaning."""
    if surface and not tint and int(snapshot.dim) == 3:
        return [Entry("water view", None), Entry("water (a lit surface)", _rgb(palette.WATER_COLOUR))]
    if surface and not tint:
        return [
            Entry("water view", None),
            Entry("water at the surface", _rgb(palette.WATER_SHALLOW)),
            Entry("deep water", _rgb(palette.WATER_DEEP)),
            Entry("spray and drops", _rgb(palette.WATER_SPRAY)),
        ]
    title = f"water by {color_mode}" if surface else f"colour: {color_mode}"
    out = [Entry(title, None)]
    if color_mode == "level":
        stats = getattr(snapshot, "stats", {}) or {}
        for lvl in range(int(snapshot.levels)):
            tag = " (finest)" if lvl == 0 and snapshot.levels > 1 else ""
            count = stats.get(f"n_level_{lvl}")
            count = f": {count}" if count is not None else ""
            out.append(Entry(f"level {lvl}{tag}{count}", _rgb(palette.level_colour(lvl))))
    elif color_mode == "kind":
        for code, name in enumerate(palette.KIND_NAMES):
            out.append(Entry(name, _rgb(palette.KIND_COLOURS[code])))
    elif color_mode == "speed":
        top = palette.default_speed_scale(snapshot.domain_min, snapshot.domain_max)
        for t in (0.0, 0.25, 0.5, 0.75, 1.0):
            more = " and above" if t == 1.0 else ""
            out.append(Entry(f"{t * top:.2f} m/s{more}", _rgb(palette.speed_colormap(np.array([t]))[0])))
    elif color_mode == "density":
        hw = palette.DENSITY_RATIO_HALF_RANGE
        for t in (0.0, 0.25, 0.5, 0.75, 1.0):
            ratio = 1.0 + (2.0 * t - 1.0) * hw
            tag = {0.0: " and below", 0.5: " (rest)", 1.0: " and above"}.get(t, "")
            out.append(Entry(f"rho/rho0 {ratio:.3f}{tag}", _rgb(palette.density_colormap(np.array([t]))[0])))
    return out


def box_px(window_size, rows: int = MAX_ROWS) -> tuple[int, int, int, int]:
    """(x, y, width, height) in pixels, y down, of a legend of ``rows`` lines with its
    swatch strip."""
    w, h = window_size
    width = SWATCH_STRIP_PX + CHAR_PX * CHARS + 2 * PAD_PX + 8
    height = TITLE_PX + 2 * PAD_PX + LINE_PX * rows
    return MARGIN_PX, MARGIN_PX, min(width, w - 2 * MARGIN_PX), min(height, h - 2 * MARGIN_PX)


def lines(snapshot, color_mode: str, surface: bool = False, tint: bool = False) -> list[Entry]:
    """Every line of the panel: the simulated time with the title, then the entries."""
    title, *rest = entries(snapshot, color_mode, surface, tint)
    return [Entry(f"t = {float(snapshot.time):.3f} s  {title.text}", None)] + rest


def swatch_triangles(rows: list[Entry], window_size, box=None):
    """The strip and a square per coloured row: triangles (6k, 2) in canvas coordinates
    (y up) and their colours (6k, 3). ``box``: the legend's (box_px)."""
    w, h = window_size
    x, y, _, height = box or box_px(window_size, len(rows))
    quads = [((x, y, SWATCH_STRIP_PX, height), STRIP_COLOUR)]
    for i, row in enumerate(rows):
        if row.colour is None:
            continue
        top = y + TITLE_PX + PAD_PX + i * LINE_PX + (LINE_PX - 4 - SWATCH_PX) / 2.0 + 1.0
        left = x + (SWATCH_STRIP_PX - SWATCH_PX) / 2.0 + 2.0
        quads.append(((left, top, SWATCH_PX, SWATCH_PX), row.colour))
    tri, col = [], []
    for (x0, y0, qw, qh), colour in quads:
        a, b, c, d = (x0, y0), (x0 + qw, y0), (x0 + qw, y0 + qh), (x0, y0 + qh)
        tri += [a, b, c, a, c, d]
        col += [colour] * 6
    tri = np.asarray(tri, np.float64)
    tri[:, 0] /= w
    tri[:, 1] = 1.0 - tri[:, 1] / h
    return tri, np.asarray(col, np.float32)


def draw_panel(gui, rows: list[Entry], window_size, box=None) -> None:
    """The legend's ImGui panel, right of its swatch strip. ``box``: its (box_px)."""
    w, h = window_size
    x, y, width, height = box or box_px(window_size, len(rows))
    px = x + SWATCH_STRIP_PX
    # ImGui places and sizes a panel when it first appears: a name per place and size
    with gui.sub_window(f"Legend##{w}x{h},{height}", px / w, y / h, (width - SWATCH_STRIP_PX) / w, height / h):
        for row in rows:
            gui.text(row.text)
