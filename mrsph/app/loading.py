"""The window's loading panel: "opening SCENE", what its simulation is doing and for how
long, while the window goes on drawing the scene it leaves (paused, dimmed).

The panel is sized to its lines (ImGui's default font: 7 px a character, 17 px a line),
so no text runs past its edge, and centred on the area the window gives the scene.
"""

from __future__ import annotations

import time

from .host import STAGES

TITLE_COLOUR = (1.0, 0.85, 0.4)
TEXT_COLOUR = (0.9, 0.9, 0.9)
HINT_COLOUR = (0.65, 0.68, 0.72)
#: ImGui's default font and layout (GGUI 1.7.4): glyph width, line pitch, title bar,
#: window padding; a panel fits ``chars`` x ``lines`` of text with these.
CHAR_PX = 7
LINE_PX = 17
TITLE_PX = 19
PAD_PX = 8
#: After this long the panel says why a first run takes long.
SLOW_S = 6.0
ESC_LINE = "Esc quits"
SLOW_LINE = "a scene's first run compiles its kernels (up to a minute); later runs read Taichi's cache"
IN_PROCESS_LINE = "in one process each new scene compiles again (see docs/app.md)"


def panel_size(lines: list[str]) -> tuple[int, int]:
    """Pixels (width, height) of a panel that shows ``lines`` whole."""
    chars = max((len(t) for t in lines), default=10)
    return CHAR_PX * chars + 2 * PAD_PX + 8, TITLE_PX + 2 * PAD_PX + LINE_PX * len(lines)


def loading_lines(opening, separate: bool = True, now: float | None = None):
    """The panel's lines for an ``Opening`` (mrsph.app.switch): [(text, colour)], and
    the texts its size is made for (the same while it opens: a panel that changed size
    would be a new one, which ImGui leaves out of its first frame)."""
    now = time.perf_counter() if now is None else now
    waited = now - opening.started
    stage = STAGES.get(getattr(opening.handle, "stage", ""), "loading")
    hint = SLOW_LINE if separate else IN_PROCESS_LINE
    lines = [
        (f"opening {opening.label}", TITLE_COLOUR),
        (f"{stage} ... {waited:.1f} s", TEXT_COLOUR),
        (hint if waited > SLOW_S else "", HINT_COLOUR),
        (ESC_LINE, HINT_COLOUR),
    ]
    longest = max(STAGES.values(), key=len)
    sized = [lines[0][0], f"{longest} ... 999.9 s", hint, ESC_LINE]
    return lines, sized


def loading_panel(window, area, lines, sized=None) -> None:
    """Add the panel to the frame being drawn, centred on ``area`` (x0, y0, x1, y1 in
    pixels, y down) and sized for ``sized`` (default: the lines); nothing without lines."""
    if not lines:
        return
    w, h = window.get_window_shape()
    pw, ph = panel_size(sized or [t for t, _ in lines])
    pw, ph = min(pw, w - 2 * PAD_PX), min(ph, h - 2 * PAD_PX)
    x0, y0, x1, y1 = area
    x = int(max(min((x0 + x1 - pw) / 2, w - pw - PAD_PX), PAD_PX))
    y = int(max(min((y0 + y1 - ph) / 2, h - ph - PAD_PX), PAD_PX))
    gui = window.get_gui()
    # ImGui places and sizes a panel when it first appears: a name per place and size
    # ("##..." is not shown)
    with gui.sub_window(f"Loading##{x},{y},{pw}x{ph}", x / w, y / h, pw / w, ph / h):
        for text, colour in lines:
            gui.text(text, color=colour)
