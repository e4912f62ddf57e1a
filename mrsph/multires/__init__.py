"""Adaptive multiresolution (METHOD.md §2–6): the levels' topology and their coupling.

- ``topology.py``: ``Multires``, the adaptivity pass (criteria, split, merge, release,
  gather) that changes which particles exist and how they are linked, with
  ``placement.py`` (where a split's children go), ``gather.py`` (virtual parents
  pooling their groups before a merge) and ``absorb.py`` (groups too light to merge,
  given to a coarse neighbour);
- ``coupling.py``: one object per ``adaptivity.coupling`` mode (``Uniform`` without
  adaptivity), whose hooks the density, force and integration passes call;
- ``limiter.py``: the virtual-mass limiter the coupling runs before the density pass;
- ``fade.py``: the compression a split puts on its children, faded out of the pressure.
"""

from .coupling import Symmetric, Uniform, Variational, make as make_coupling
from .fade import SplitFade
from .topology import COUNTERS, Multires, sampling_offsets

__all__ = ["COUNTERS", "Multires", "SplitFade", "Symmetric", "Uniform", "Variational", "make_coupling",
           "sampling_offsets"]
