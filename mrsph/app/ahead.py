"""Building ahead: the simulations a key is likely to open next, built in the background
while the window runs another, so that the switch finds them ready.

Why. A scene seen on this machine still takes 8-11 s to open in a new process on a
2-core CPU (docs/app.md): Taichi's offline cache keeps a kernel's optimised LLVM IR, not
its machine code, so a new process turns each kernel into IR in Python again (2.6 s for
demo_2d) and generates its machine code again (5.3 s, most of it for the three fused
kernels of a step and the level pass). Neither can be skipped from Python. What can be
done is to do it before the key is pressed.

What. After a scene has run for ``AFTER_S``, the window names what ``s`` (the next
solver), Tab and shift+Tab (the next and the previous scene) would open, in that order,
the first ``count()`` of them. The likeliest not yet built is built in a worker of its
own, at a lower priority (``NICE``: the running scene and the window come first), then
the next, until all are ready (one named lower after a switch goes on beside it). A
switch to one of them takes it as it is: ready (a fraction of a second), or still
building (the rest of its build). When the window moves on, those it no longer
names are kept like a scene it left, if ready (``Sims.put_back``), or ended, if not.

``MRSPH_AHEAD=N`` names at most N (0: none); the default is all three. Each holds its
simulation's memory (demo_2d ~180 MB, demo_3d ~320 MB) besides the ``host.KEEP`` kept.
"""

from __future__ import annotations

import collections
import os

#: How many of the next solver, next scene, previous scene to build ahead (default).
DEFAULT_COUNT = 3
COUNT_ENV = "MRSPH_AHEAD"
#: Seconds a scene runs before the window builds ahead of it (its first frames first).
AFTER_S = 1.0
#: The niceness of a worker building ahead (a switch to it restores 0 where allowed).
NICE = 10


def count(environ=os.environ) -> int:
    """How many simulations to build ahead: ``MRSPH_AHEAD`` where set, else all three."""
    raw = environ.get(COUNT_ENV)
    if raw is None or raw == "":
        return DEFAULT_COUNT
    try:
        n = int(raw)
    except ValueError:
        n = -1
    if not 0 <= n <= DEFAULT_COUNT:
        raise ValueError(f"{COUNT_ENV}={raw!r}: expected a whole number from 0 to {DEFAULT_COUNT}")
    return n


class Ahead:
    """The simulations being built, or built, ahead of a switch (never shown yet)."""

    def __init__(self, sims, key_of):
        """sims: the window's ``host.Sims``; key_of(name, overrides): its keys."""
        self.sims, self.key_of = sims, key_of
        self.handles: collections.OrderedDict = collections.OrderedDict()  # key -> handle, wanted order
        self.wanted: list = []  # [(key, name, overrides)]
        self.failed: set = set()  # keys whose build failed: not tried again

    def take(self, key):
        """The handle built ahead for ``key``, now the window's (None if there is none)."""
        handle = self.handles.pop(key, None)
        if handle is None or not handle.alive() or handle.state == "failed":
            if handle is not None:
                handle.close()
            return None
        handle.hurry()
        return handle

    def want(self, items: list) -> None:
        """Build ahead ``items`` ([(name, overrides)], likeliest first); the handles of
        others are kept if ready, ended if not."""
        self.wanted = [(self.key_of(name, ov), name, ov) for name, ov in items]
        keys = {k for k, _, _ in self.wanted}
        for key in [k for k in self.handles if k not in keys]:
            self.sims.put_back(self.handles.pop(key))

    def tick(self, start: bool = True) -> None:
        """Follow the builds; where ``start``, start the likeliest one not built unless
        a likelier one is building (one named lower after a switch goes on beside it)."""
        for key, handle in list(self.handles.items()):
            if handle.poll() in ("failed", "dead"):
                self.failed.add(key)
                handle.close()
                del self.handles[key]
        if not start:
            return
        for key, name, overrides in self.wanted:
            if key in self.failed or key in self.sims.kept:
                continue
            if key in self.handles:
                if self.handles[key].state == "busy":
                    return
                continue
            handle = self.sims.spawn(name, overrides, nice=NICE)
            if handle is not None:
                self.handles[key] = handle
            return

    def ready(self) -> int:
        """How many are ready to open."""
        return sum(h.state == "ready" for h in self.handles.values())

    def close(self) -> None:
        for handle in self.handles.values():
            handle.close()
        self.handles.clear()
        self.wanted = []
