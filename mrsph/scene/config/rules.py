"""The cross-field rules of a scene, after each key has passed the schema: fluid inside
the domain and outside the obstacles, levels that exist, a capacity that holds the
fluid, the emitters' discs, and each pressure solver's own rules (its package's
``rules``); ``validate`` runs the schema and then these."""

from __future__ import annotations

import math

from mrsph.limits import AUTO_SKIN, LATTICE_EPS, MAX_GRID_CELLS, MAX_OBSTACLES, max_capacity
from mrsph.pressure import SOLVERS, spec

from .checks import OPTION_FLAG, Checker, fmt_value
from .schema import SCHEMA, SHAPES

# Automatic capacity = int(CAPACITY_MARGIN * lattice + emitted) + CAPACITY_SLACK: splits
# turn one particle into 2^d and virtual particles need slots too, hence the margin.
CAPACITY_MARGIN = 1.5
CAPACITY_SLACK = 1024
# An emitter counts for at most this long when sizing automatic capacity (its default
# stop time of 1e9 s would otherwise ask for unbounded memory).
EMIT_HORIZON_S = 60.0


def lattice_count(blocks: list[dict], s0: float) -> int:
    return sum(
        math.prod(max(0, math.floor((hi - lo) / s0 + LATTICE_EPS)) for lo, hi in zip(b["min"], b["max"]))
        for b in blocks
    )


def _emitted(emitters: list[dict], s0: float, dim: int, top_level: int) -> int:
    """Particles the emitters add within EMIT_HORIZON_S, each at its own level but no
    coarser than ``top_level``, the run's coarsest (0 with adaptivity off), as the solver
    emits them."""
    total = 0
    for e in emitters:
        s = s0 * 2 ** min(e["level"], top_level)
        speed = math.sqrt(sum(c * c for c in e["velocity"]))
        duration = min(e["stop"] - e["start"], EMIT_HORIZON_S)
        total += math.ceil((2 * e["radius"] / s) ** (dim - 1) * speed / s * duration)
    return total


def given(*values) -> bool:
    return all(v is not None for v in values)


def block_given(b) -> bool:
    return bool(b) and given(b["min"], b["max"])


def _overlap(b: dict, ob: dict) -> str | None:
    """How obstacle ``ob`` is described if fluid block ``b`` overlaps it, else None."""
    if ob["shape"] == "box" and given(ob["min"], ob["max"]):
        pairs = zip(b["min"], b["max"], ob["min"], ob["max"])
        if all(a0 < b1 and b0 < a1 for a0, a1, b0, b1 in pairs):
            return f"the box {fmt_value(ob['min'])} .. {fmt_value(ob['max'])}"
    elif ob["shape"] == "sphere" and given(ob["center"], ob["radius"]):
        # squared distance from the centre to the nearest point of the block
        d2 = sum((c - min(max(c, a), b)) ** 2 for a, b, c in zip(b["min"], b["max"], ob["center"]))
        if d2 < ob["radius"] ** 2:
            return f"the sphere at {fmt_value(ob['center'])} with radius {ob['radius']!r}"
    return None


def _check_places(c: Checker, d: dict) -> None:
    """Fluid, emitters and regions inside the domain; fluid outside the obstacles."""
    dom, fluid, emitters = d["domain"], d["fluid"], d["emitters"]
    blocks = [(i, b) for i, b in enumerate(fluid["blocks"] if fluid else []) if block_given(b)]
    # an array of the wrong type is reported already: it is not also 'no fluid'
    if fluid is not None and not fluid["blocks"] and not emitters and not c.broken & {"fluid.blocks", "emitters"}:
        c.add(
            "fluid.blocks",
            "no fluid",
            "no [[fluid.blocks]] and no [[emitters]]",
            "at least one [[fluid.blocks]] or one [[emitters]]",
        )
    for shape in SHAPES:
        count = sum(1 for ob in d["obstacles"] if ob and ob["shape"] == shape)
        if count > MAX_OBSTACLES:
            c.add("obstacles", f"too many of shape {shape}", str(count), f"at most {MAX_OBSTACLES}")
    part = d.get("particles") or {}
    spacing = part.get("spacing")
    for i, b in blocks:
        if given(spacing) and spacing > 0:
            thin = [k for k, (lo, hi) in enumerate(zip(b["min"], b["max"])) if hi - lo < spacing * (1.0 - LATTICE_EPS)]
            if thin:
                c.add(
                    f"fluid.blocks.{i}",
                    "holds no particle",
                    f"min {fmt_value(b['min'])}, max {fmt_value(b['max'])}",
                    f"at least particles.spacing = {fmt_value(spacing)} m across on every axis (not on "
                    + ("axis " if len(thin) == 1 else "axes ")
                    + ", ".join("xyz"[k] for k in thin)
                    + ")",
                )
        for j, ob in enumerate(d["obstacles"]):
            what = ob and _overlap(b, ob)
            if what:
                c.add(
                    f"fluid.blocks.{i}",
                    f"overlaps obstacles.{j}",
                    f"min {fmt_value(b['min'])}, max {fmt_value(b['max'])}",
                    f"no overlap with {what}",
                )
        # each block is seeded with its own lattice: where two overlap, the fluid would
        # start at twice its density and burst apart
        for j, other in blocks:
            what = j < i and _overlap(b, {"shape": "box", "min": other["min"], "max": other["max"]})
            if what:
                c.add(
                    f"fluid.blocks.{i}",
                    f"overlaps fluid.blocks.{j}",
                    f"min {fmt_value(b['min'])}, max {fmt_value(b['max'])}",
                    f"blocks that at most touch (no overlap with {what})",
                )
    for i, cr in enumerate(d["criteria"]):
        # a region that loops over no path, or over one waypoint, never moves
        if not (cr and cr["type"] == "region" and cr["loop"]):
            continue
        path = cr["path"]
        if path is None and f"criteria.{i}.path" not in c.broken or path and len(path) < 2:
            c.add(
                f"criteria.{i}.loop",
                "nothing to repeat",
                "no path" if path is None else "a path of one waypoint",
                "a path of at least 2 waypoints with loop = true",
            )
    if not (dom and given(dom["min"], dom["max"])):
        return
    where = f"inside the domain {fmt_value(dom['min'])} .. {fmt_value(dom['max'])}"

    def inside(p) -> bool:
        return _in_box(p, dom["min"], dom["max"])

    for i, b in blocks:
        if not (inside(b["min"]) and inside(b["max"])):
            c.add(
                f"fluid.blocks.{i}",
                "outside the domain",
                f"min {fmt_value(b['min'])}, max {fmt_value(b['max'])}",
                where,
            )
    for i, e in enumerate(emitters):
        if e and e["center"] is not None and not inside(e["center"]):
            c.add(f"emitters.{i}.center", "outside the domain", fmt_value(e["center"]), where)
    for i, st in enumerate(d["stirrers"]):
        away = [w for w in (st and st["path"] or []) if not inside(w[1:])]
        if away:
            c.add(
                f"stirrers.{i}.path",
                "waypoint outside the domain",
                fmt_value(list(away[0])),
                f"every waypoint's position {where}",
            )
    for i, cr in enumerate(d["criteria"]):
        if not (cr and cr["type"] == "region" and cr["shape"] in SHAPES):
            continue
        if cr["shape"] == "sphere":
            center = cr["center"]
        else:
            center = block_given(cr) and tuple((a + b) / 2 for a, b in zip(cr["min"], cr["max"]))
        if center and not inside(center):
            c.add(f"criteria.{i}", "region centre outside the domain", fmt_value(center), where)


def mass_exact(data: dict) -> bool:
    """Whether a scene keeps its total real mass bit for bit: where every merge takes a
    full group of 2^d children (or nothing merges), splits divide by 2^d and merges add
    the parts back, exactly in binary. Partial groups (``merge_min_children`` < 2^d, or
    ``merge_remnants``) add their masses in the pool's precision: round-off, not more."""
    ad = data["adaptivity"]
    return not ad["enabled"] or (ad["merge_min_children"] == 2 ** data["dim"] and not ad["merge_remnants"])


def emitter_disc(center, radius: float, velocity, s: float):
    """Lattice points (spacing ``s``) of an emitter's disc (a segment in 2D): the points
    within ``radius`` of ``center`` in the plane normal to ``velocity``, as an (n, dim)
    numpy array. The solver emits these; the scene check keeps them in the fluid's space."""
    import numpy as np

    normal = np.asarray(velocity, np.float64)
    normal = normal / np.linalg.norm(normal)
    dim = len(normal)
    basis = np.linalg.svd(normal.reshape(1, -1))[2][1:]  # orthonormal, in the plane
    n = int(math.floor(radius / s))
    ticks = np.arange(-n, n + 1) * s
    pts = np.stack(np.meshgrid(*([ticks] * (dim - 1)), indexing="ij"), -1).reshape(-1, dim - 1)
    pts = pts[np.linalg.norm(pts, axis=1) <= radius + 1e-9]
    return np.asarray(center, np.float64) + pts @ basis


def _in_box(p, lo, hi) -> bool:
    """Whether point ``p`` lies in the closed box ``lo`` .. ``hi``."""
    return all(a <= x <= b for a, x, b in zip(lo, p, hi))


def _inside_obstacle(p, ob) -> bool:
    """Whether point ``p`` lies strictly inside obstacle ``ob``."""
    if ob["shape"] == "box":
        return all(a < x < b for a, x, b in zip(ob["min"], p, ob["max"]))
    return sum((x - c) ** 2 for x, c in zip(p, ob["center"])) < ob["radius"] ** 2


def _check_emitters(c: Checker, d: dict) -> None:
    """Every point an emitter places lies in the domain and outside every obstacle (a
    particle placed inside a solid is thrown out of it at many times the emitter's speed)."""
    dom, part, ad = d["domain"], d.get("particles") or {}, d["adaptivity"] or {}
    if not (dom and given(dom["min"], dom["max"]) and given(part.get("spacing"))):
        return
    for i, e in enumerate(d["emitters"]):
        if not (
            e
            and given(e["center"], e["radius"], e["velocity"], e["level"])
            and len(e["center"]) == len(e["velocity"]) == d["dim"]
            and any(e["velocity"])
        ):
            continue
        if not _in_box(e["center"], dom["min"], dom["max"]):
            continue  # reported by _check_places
        level = e["level"] if ad.get("enabled") else 0
        pts = emitter_disc(e["center"], e["radius"], e["velocity"], part["spacing"] * 2**level)
        outside = [p for p in pts if not _in_box(p, dom["min"], dom["max"])]
        if outside:
            c.add(
                f"emitters.{i}",
                "outlet outside the domain",
                f"centre {fmt_value(e['center'])}, radius {e['radius']!r}",
                f"a disc inside the domain {fmt_value(dom['min'])} .. {fmt_value(dom['max'])} "
                f"(its point {fmt_value([round(float(x), 6) for x in outside[0]])} is not)",
            )
        for j, ob in enumerate(d["obstacles"]):
            valid = ob and (block_given(ob) if ob["shape"] == "box" else given(ob["center"], ob["radius"]))
            if valid and any(_inside_obstacle(p, ob) for p in pts):
                c.add(
                    f"emitters.{i}",
                    f"outlet inside obstacles.{j}",
                    f"centre {fmt_value(e['center'])}, radius {e['radius']!r}",
                    f"a disc clear of the {ob['shape']} obstacles.{j}",
                )


def _check_values(c: Checker, d: dict) -> None:
    """Rules between two keys of one table."""
    for i, e in enumerate(d["emitters"]):
        if e and e["velocity"] is not None and not any(e["velocity"]):
            c.add(
                f"emitters.{i}.velocity",
                "zero velocity",
                fmt_value(e["velocity"]),
                "a non-zero vector; the emitting disc faces along it",
            )
        if e and given(e["start"], e["stop"]) and e["stop"] <= e["start"]:
            c.add(f"emitters.{i}.stop", "not after start", fmt_value(e["stop"]), f"a number > start = {e['start']!r}")
    fl = d["fluid"]
    if fl and given(fl["settle"]) and fl["settle"] > 0:
        # the settle runs before t = 0, where an emitter or a stirrer's path has no time
        for table in ("emitters", "stirrers"):
            if d[table]:
                c.add("fluid.settle", f"with {table}", fmt_value(fl["settle"]), f"0 in a scene with [[{table}]]")
    if fl and fl["solver"] in SOLVERS:  # the running solver's own rules (its package)
        spec(fl["solver"]).rules(c, d)
    phys = d["physics"]
    if phys and given(phys["dt_min"], phys["dt_max"]) and phys["dt_min"] >= phys["dt_max"]:
        c.add(
            "physics.dt_min", "not below dt_max", fmt_value(phys["dt_min"]), f"a number < dt_max = {phys['dt_max']!r}"
        )
    for name in ("camera_position", "camera_lookat"):
        if d["dim"] == 2 and d["render"] and d["render"][name] is not None:
            c.add(f"render.{name}", "only for 3D scenes", fmt_value(d["render"][name]), "no camera keys when dim = 2")


def _check_levels(c: Checker, d: dict) -> None:
    """Every level named exists; resolve the automatic adaptivity values."""
    ad, dim = d["adaptivity"], d["dim"]
    if not ad:
        return
    levels = ad["levels"]
    if levels is not None:
        if ad["enabled"] and levels < 2:
            c.add(
                "adaptivity.levels",
                "too few levels for adaptivity",
                str(levels),
                "an integer >= 2 when adaptivity.enabled = true",
            )
        named = [(f"emitters.{i}.level", e and e["level"]) for i, e in enumerate(d["emitters"])]
        named += [(f"criteria.{i}.level", cr and cr["level"]) for i, cr in enumerate(d["criteria"])]
        named += [("adaptivity.background_level", ad["background_level"])]
        for key, level in named:
            if level is not None and level >= levels:
                c.add(key, "no such level", str(level), f"an integer < adaptivity.levels = {levels}")
        # with adaptivity off everything stays at level 0: resolve for one level then
        used = levels if ad["enabled"] else 1
        if ad["background_level"] == -1:
            ad["background_level"] = used - 1
        part, dom = d["particles"], d["domain"]
        if ad["band"] == 0.0 and part and given(part["spacing"], part["support"]):
            ad["band"] = 2 * part["support"] * part["spacing"] * 2 ** (used - 1)
        # a level whose support reaches across the whole domain has no fluid to resolve:
        # its few particles see mostly their own mirror images
        if used > 1 and part and dom and given(part["spacing"], part["support"], dom["min"], dom["max"]):
            side = min(b - a for a, b in zip(dom["min"], dom["max"]))
            h0 = part["support"] * part["spacing"]
            if h0 * 2 ** (used - 1) > side:
                fit = max(1, int(math.floor(math.log2(side / h0) + 1e-9)) + 1) if side >= h0 else 1
                c.add(
                    "adaptivity.levels",
                    "too many for the domain",
                    str(levels),
                    f"at most {fit}: level {used - 1}'s support radius, "
                    f"{fmt_value(h0 * 2 ** (used - 1))} m, exceeds the domain's smallest side, "
                    f"{fmt_value(side)} m",
                )
    if ad["merge_min_children"] is not None:
        if ad["merge_min_children"] > 2**dim:
            c.add(
                "adaptivity.merge_min_children",
                "more children than a parent has",
                str(ad["merge_min_children"]),
                f"an integer <= 2^dim = {2**dim}, or 0",
            )
        ad["merge_min_children"] = ad["merge_min_children"] or 2 ** (dim - 1)


def _check_skin(c: Checker, d: dict) -> None:
    """The lists' skin is a share of h >= 0, or -1: the solver's choice (``AUTO_SKIN``)."""
    part, fl = d["particles"], d["fluid"]
    if not part or part["skin"] is None:
        return
    if -1.0 < part["skin"] < 0.0:
        c.add("particles.skin", "out of range", fmt_value(part["skin"]), "a share of h >= 0, or -1 for the solver's")
    elif part["skin"] == -1.0 and fl and fl["solver"] in SOLVERS:
        part["skin"] = AUTO_SKIN.get(fl["solver"], 0.0)


def _check_sizes(c: Checker, d: dict) -> None:
    """The neighbour grid and the particle pool are big enough; resolve capacity 0."""
    dom, part, fluid, emitters = d["domain"], d["particles"], d["fluid"], d["emitters"]
    if not (part and given(part["spacing"], part["support"])):
        return
    s0, h0 = part["spacing"], part["spacing"] * part["support"]
    if dom and given(dom["min"], dom["max"]):
        cells = math.prod(max(0.0, b - a) / h0 for a, b in zip(dom["min"], dom["max"]))
        if cells > MAX_GRID_CELLS:
            c.add(
                "domain",
                "too large for the neighbour grid",
                f"{cells:.3g} cells of size h0 = {h0:g} m",
                f"<= {MAX_GRID_CELLS:.0e} cells; raise particles.spacing or shrink the domain",
            )
    skin = part["skin"] if part["skin"] is not None and part["skin"] >= 0.0 else 0.0
    limit = max_capacity(d["dim"], skin)
    if part["capacity"] is not None and part["capacity"] > limit:
        c.add(
            "particles.capacity",
            "too many slots for the neighbour lists",
            str(part["capacity"]),
            f"<= {limit} in {d['dim']}D" + (f" with particles.skin = {fmt_value(skin)}" if skin > 0.0 else ""),
        )
        return
    if not (fluid and all(block_given(b) for b in fluid["blocks"])) or part["capacity"] is None:
        return
    need = lattice_count(fluid["blocks"], s0)
    if 0 < part["capacity"] < need:
        c.add(
            "particles.capacity",
            "too small for the fluid blocks",
            str(part["capacity"]),
            f">= {need}, the lattice points of fluid.blocks; raise particles.capacity or use 0 for automatic",
        )
    elif part["capacity"] == 0 and all(e and None not in e.values() for e in emitters):
        ad = d["adaptivity"] or {}
        top = (ad.get("levels") or 1) - 1 if ad.get("enabled") else 0
        emitted = _emitted(emitters, s0, d["dim"], top)
        part["capacity"] = int(CAPACITY_MARGIN * need + emitted) + CAPACITY_SLACK
        if part["capacity"] > limit:
            c.add(
                "particles.spacing",
                "too many particles for the pool",
                f"{part['capacity']:.3g} slots needed at spacing {s0:g} m",
                f"<= {limit} in {d['dim']}D; raise particles.spacing or shrink the fluid",
            )


def _check_enabled(c: Checker, raw: dict) -> None:
    """Criteria or several levels without ``adaptivity.enabled``: the refinement the scene
    describes would silently not happen (enabled defaults to false)."""
    ad = raw.get("adaptivity")
    ad = ad if isinstance(ad, dict) else {}
    if "enabled" in ad:
        return
    named = []
    if isinstance(raw.get("criteria"), list) and raw["criteria"]:
        named.append("[[criteria]]")
    if isinstance(ad.get("levels"), int) and not isinstance(ad["levels"], bool) and ad["levels"] > 1:
        named.append(f"adaptivity.levels = {ad['levels']}")
    if named:
        c.add(
            "adaptivity.enabled",
            "not set",
            " and ".join(named) + " given",
            "adaptivity.enabled = true to refine, or false to run uniform at the finest spacing",
        )


def validate(raw, label: str, overridden: list[str], flag: str = OPTION_FLAG) -> tuple[dict | None, list[str]]:
    c = Checker(label, overridden, flag)
    dim = raw.get("dim") if isinstance(raw, dict) else None
    dim = dim if dim in (2, 3) and isinstance(dim, int) and not isinstance(dim, bool) else None
    d = c.table(SCHEMA, raw, "", dim)
    if d is not None and dim is not None:
        for check in (_check_places, _check_values, _check_levels, _check_emitters, _check_skin, _check_sizes):
            check(c, d)
        if not c.problems:  # a forgotten switch, worth a line once the rest is right
            _check_enabled(c, raw)
    return d, c.problems
