"""The window's loading frames: "loading SCENE (compiling ...)" while a scene is built
or its step compiles, so that a switch (Tab) never freezes the window silently.

Taichi compiles on the main thread only, so the window cannot draw while a compile runs:
it draws one frame that says what is coming just before, and answers an Esc pressed
meanwhile when the compile ends.
"""

from __future__ import annotations

#: Where the message goes: the middle of the window, wide enough for a long scene name.
PANEL_POS = (0.3, 0.42)
PANEL_SIZE_PX = (420, 70)
TEXT_COLOUR = (1.0, 0.85, 0.4)
ESC_LINE = "Esc quits (answered when this compile ends)"


def loading_panel(window, size, text: str | None) -> None:
    """Add the loading panel to the frame being drawn (nothing when ``text`` is None)."""
    if not text:
        return
    w, h = size
    gui = window.get_gui()
    with gui.sub_window(
        "Loading", PANEL_POS[0], PANEL_POS[1], min(PANEL_SIZE_PX[0] / w, 0.6), min(PANEL_SIZE_PX[1] / h, 0.3)
    ):
        gui.text(text, color=TEXT_COLOUR)
        gui.text(ESC_LINE)


def show_loading_frame(window, renderer, text: str, escape, drawn=None) -> bool:
    """Show one frame that says ``text`` on the background (nothing else: no Taichi
    kernel runs while a scene is half built); False when ``escape`` was pressed since
    the last frame (the caller quits). ``drawn()`` is called between drawing and
    showing (the test hook's screenshot)."""
    import taichi as ti

    renderer.canvas.set_background_color(tuple(float(c) for c in renderer.style.background))
    loading_panel(window, renderer.size, text)
    if drawn is not None:
        drawn()
    window.show()
    return not any(e.key == escape for e in window.get_events(ti.ui.PRESS))
