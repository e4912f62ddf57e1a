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
raster    pure-numpy software rasteriser (fallback when Vulkan is missing)
record    ``record(sim, out, frames, ...)``: mp4 / gif / png sequence
mouse     mouse state machine -> ``Disturbance`` (pure logic)
window    ``run_window(...)``: the interactive app
pointer   the window's drags: camera, HUD or fluid (the mouse's disturbance)
marks     what the window draws over the water: stirrers and the mouse's reach
loading   the window's "loading SCENE (compiling ...)" frames
hooks     the window's stats lines and screenshots (test hooks)
hud       the window's HUD and help panels
probe     can a GGUI window open here (asked in a subprocess)
fake      a tiny stand-in simulation for tests and demos
__main__  ``python -m mrsph.app [scene]`` (``--fake 2|3`` for the stand-in)
"""
