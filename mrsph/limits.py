"""The limits that the scene's validation and the physics share: sizes of fixed Taichi
fields and of the neighbour lists, and the ranges they bound. Taichi-free, imported by
both layers (``scene.config`` checks a scene against them, the fields are sized by them)."""

import math

# Counted in cells of h0 (the level-0 grid splits those 2x in 2D, 4x in 3D along its rows,
# grid.CELLS_PER_SUPPORT); past ~50e6 such cells its per-cell arrays alone take hundreds
# of MB, so such a domain is almost surely a unit slip.
MAX_GRID_CELLS = 50e6
# Neighbour list length per dimension (sph/neighbours.py): about 3x the neighbour count of the
# rest lattice (12 in 2D, 26 in 3D within h = 2 s), so that only a strongly compressed
# particle overflows (it then loops over the grid instead; results are the same).
MAX_NEIGHBOURS = {2: 40, 3: 80}
# The largest skin (particles.skin, a share of h): lists of everything within (1 + skin) h
# grow as (1 + skin)^dim, 8x at a skin of 1 in 3D.
MAX_SKIN = 1.0
# particles.skin = -1 takes the solver's (docs/performance.md, "Neighbour lists that
# outlive a step"): none yet. dfsph's and pbf's steps move a particle past any small skin;
# wcsph gains 8-14 % at 0.1, but demo_2d's still cursor then threw one particle to 2.0 m/s
# (0.55 without), which is not understood, so a skin is a scene's choice.
AUTO_SKIN = {"wcsph": 0.0, "dfsph": 0.0, "pbf": 0.0}


def skin_list_length(dim: int, skin: float, listed: int | None = None) -> int:
    """Entries of a skin list (everything within (1 + skin) h, ``sph/neighbours.py``): the
    list's length scaled by the ball's volume, (1 + skin)^dim; 0 without a skin."""
    listed = MAX_NEIGHBOURS[dim] if listed is None else listed
    return 0 if skin <= 0.0 else math.ceil(listed * (1.0 + skin) ** dim)


def max_capacity(dim: int, skin: float = 0.0) -> int:
    """Particle slots: the neighbour lists hold MAX_NEIGHBOURS + 1 entries a slot (and the
    skin lists ``skin_list_length`` + 1) and Taichi indexes a field with 32 bits, so
    slots x 41 (2D) or x 81 (3D) must stay below 2^31: 52 M and 26 M slots without a
    skin, tens of GB at 0.3-0.6 kB a slot. Refused before Taichi tries to allocate (9e7
    slots in 2D ended in an int32 overflow, then the OOM killer)."""
    widest = max(MAX_NEIGHBOURS[dim], skin_list_length(dim, skin)) + 1
    return (2**31 - 1) // widest // 10**6 * 10**6


MAX_CAPACITY = {d: max_capacity(d) for d in (2, 3)}  # without a skin
# Frames per second (run.fps, --fps): a GIF holds a frame at most 655 s, and a
# frame interval of a millisecond is already far below any time step that matters.
FPS_RANGE = (0.1, 1000.0)
# Sizes of the Taichi fields that hold a scene's shapes, criteria and stirrers (allocated
# once, so that a scene's count does not recompile kernels); a scene asking for more is
# refused here rather than cut short where the fields are filled.
MAX_OBSTACLES = 32  # of each shape (boundary.py)
MAX_CRITERIA = 16  # criteria.py
MAX_STIRRERS = 7  # interaction.py: one disturbance slot is the mouse's
# Slack of floor() in the lattice count, so that 0.3 / 0.1 = 2.9999999999999996 counts 3.
LATTICE_EPS = 1e-9
