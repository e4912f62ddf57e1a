"""Everything with a window: rendering, recording, mouse interaction.

Nothing heavy happens at import: Taichi, imageio and tqdm are imported inside the
modules that need them (``render``, ``window``, ``record``), so ``import mrsph.app``
costs nothing and the physics never pulls in GUI code by accident.

Modules
-------
palette   level / kind colours and colormaps (numpy only)
view      letterboxed 2D view and orbit camera (numpy only; shared by every renderer)
geometry  domain / obstacle outlines, fills and 3D shells (numpy only)
render    the GGUI renderer used by the window and by offscreen recording
legend    what the colours mean, each with its swatch (both renderers)
raster    pure-numpy software rasteriser (fallback when Vulkan is missing)
record    ``record(sim, out, frames, ...)``: mp4 / gif / png sequence
mouse     mouse state machine -> ``Disturbance`` (pure logic)
window    ``run_window(...)``: the interactive app
host      the window's simulations, each in a process of its own, kept for a switch back
switch    the window's scene and solver switches
keys      the window's keys, one table (README, help panel, ``main.py keys``)
pointer   the window's drags: camera, HUD or fluid (the mouse's disturbance)
marks     what the window draws over the water: stirrers and the mouse's reach
loading   the window's "opening SCENE" panel
hooks     the window's stats lines and screenshots (test hooks)
hud       the window's HUD and help panels
probe     can a GGUI window open here (asked in a subprocess)
__main__  ``python -m mrsph.app [scene]`` (``--fake 2|3``: the tests' stand-in)
"""
