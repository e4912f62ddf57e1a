"""The scene schema: every key a scene file may hold, with its type, unit, default, range
and meaning (``SCHEMA``; docs/scenes.md is generated from it by tools/scene_docs.py). A
pressure solver's own table (``[dfsph]``, ...) comes from its package in
``mrsph.pressure``."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from mrsph.limits import AUTO_SKIN, FPS_RANGE, MAX_CAPACITY, MAX_CRITERIA, MAX_OBSTACLES, MAX_SKIN, MAX_STIRRERS
from mrsph.pressure import SOLVERS, spec

REQUIRED = object()  # default of a key that the scene must give


# ----------------------------------------------------------------------------- schema
@dataclass
class Key:
    """One scalar or vector key. ``kind``: float int bool str choice vec vec3 path."""

    kind: str
    default: Any = REQUIRED  # REQUIRED, None (optional), a value, or a function of dim
    range: str = ""  # "> 0", ">= 0", "[0, 1]", "(0, 1]"; per component for vectors
    unit: str = ""
    doc: str = ""
    choices: tuple = ()
    min_items: int = 0  # least number of waypoints of a path
    default_doc: str = ""  # how docs/scenes.md shows a default that depends on dim


@dataclass
class Table:
    keys: dict
    doc: str = ""
    required: bool = False
    switch: str = ""  # key whose value picks one of ``variants`` (extra keys)
    variants: dict = field(default_factory=dict)


@dataclass
class Array:
    item: Table
    doc: str = ""
    max_items: int = 0  # most entries; 0 = no limit


ZEROS = dict(default=lambda dim: (0.0,) * dim, default_doc="zeros")
BOX = Table(
    {
        "min": Key("vec", unit="m", doc="lower corner"),
        "max": Key("vec", unit="m", doc="upper corner, > min in every component"),
    }
)
SPHERE = Table(
    {"center": Key("vec", unit="m", doc="centre"), "radius": Key("float", range="> 0", unit="m", doc="radius")}
)
SHAPES = {"box": BOX, "sphere": SPHERE}
SHAPE = Key("choice", choices=("box", "sphere"), doc="sphere is a circle in 2D")


def solver_table(name: str) -> Table | None:
    """Solver ``name``'s own table of keys (its package's ``TABLE``), or None."""
    table = spec(name).TABLE
    if table is None:
        return None
    keys, doc = table
    return Table({k: Key(*args, **kwargs) for k, (args, kwargs) in keys.items()}, doc=doc)


#: the solvers' own tables, by name, placed in the schema after [fluid]
SOLVER_TABLES = {name: t for name in SOLVERS if (t := solver_table(name)) is not None}

SCHEMA = Table(
    required=True,
    keys={
        "description": Key("str", doc="one line saying what the scene shows"),
        "dim": Key("int", range="[2, 3]", doc="number of space dimensions; y is up"),
        "domain": Table(
            required=True,
            doc="The box holding the fluid; its walls are solid.",
            keys={
                "min": Key("vec", unit="m", doc="lower corner"),
                "max": Key("vec", unit="m", doc="upper corner, > min in every component"),
                "restitution": Key(
                    "float", 0.0, "[0, 1]", doc="fraction of the normal velocity reflected at walls and obstacles"
                ),
                "friction": Key("float", 0.0, "[0, 1]", doc="fraction of the tangential velocity removed on contact"),
            },
        ),
        "particles": Table(
            required=True,
            keys={
                "spacing": Key(
                    "float",
                    range="> 0",
                    unit="m",
                    doc="initial spacing s0 of the finest level 0; level n has spacing 2^n s0",
                ),
                "support": Key("float", 2.0, "[1.5, 4]", doc="support radius over spacing: h0 = support * spacing"),
                "skin": Key(
                    "float",
                    -1.0,
                    f"[-1, {MAX_SKIN:g}]",
                    doc="margin of the neighbour lists, a share of h: lists of everything within (1 + skin) h, "
                    "kept across steps until a particle has moved skin h / 2 or the particles changed; "
                    "0 = a new list every step; -1 = the solver's choice ("
                    + ", ".join(f"{k} {v:g}" for k, v in AUTO_SKIN.items())
                    + ")",
                ),
                "capacity": Key(
                    "int",
                    0,
                    ">= 0",
                    doc=f"particle slots, at most "
                    f"{MAX_CAPACITY[2] // 10**6} million (2D) or {MAX_CAPACITY[3] // 10**6} "
                    "million (3D) without a skin, fewer with one (particles.skin); 0 = automatic: "
                    "int(1.5 * lattice count + emitted) + 1024; the pool rounds it up to "
                    "an odd multiple of 16 (so that its arrays do not alias in the cache)",
                ),
                "precision": Key("choice", "f32", choices=("f32", "f64"), doc="float precision"),
            },
        ),
        "fluid": Table(
            required=True,
            keys={
                "rest_density": Key("float", 1000.0, "> 0", "kg/m^3", "rest density rho0"),
                "viscosity": Key(
                    "float",
                    1.0,
                    ">= 0",
                    "Pa s",
                    "dynamic viscosity mu; with fluid.artificial_viscosity it is the scheme's dissipation, "
                    "so it sits far above water's 0.001 (Müller et al. 2003 used 3.5)",
                ),
                "solver": Key(
                    "choice",
                    SOLVERS[0],
                    choices=SOLVERS,
                    doc="pressure solver (mrsph/pressure/): " + "; ".join(spec(name).DOC for name in SOLVERS),
                ),
                "eos": Key(
                    "choice",
                    "linear",
                    choices=("linear", "tait"),
                    doc="equation of state (wcsph; with every solver the hydrostatic start's density): "
                    "linear p = k (rho - rho0); tait p = rho0 k / gamma ((rho/rho0)^gamma - 1); "
                    "both have sound speed sqrt(k) at rest",
                ),
                "stiffness": Key("float", 1000.0, "> 0", "m^2/s^2", "k, the squared sound speed"),
                "gamma": Key(
                    "float", 7.0, "[1, 10]", doc="exponent of the Tait equation (wcsph, and the hydrostatic start)"
                ),
                "clamp_negative_pressure": Key(
                    "bool", True, doc="wcsph: clamp pressure at 0 (no clumping at the free surface)"
                ),
                "artificial_viscosity": Key(
                    "float",
                    0.2,
                    "[0, 1]",
                    doc="alpha of Monaghan's artificial "
                    "viscosity (1992), acting on approaching pairs with the sound "
                    "speed: it damps the particle-scale motion that viscosity alone "
                    "leaves ringing (a resting pool's lattice rearranging under its "
                    "own weight); 0 = off",
                ),
                "artificial_viscosity_cap": Key(
                    "float",
                    0.15,
                    "[0, 0.35]",
                    doc="kappa of a cap on the artificial viscosity, alpha c <= kappa h / dt (h the "
                    "level's support, dt the last step's); 0 = no cap. Explicit, the term "
                    "overshoots past dt = 0.35 h / (alpha c), which dfsph's step, tied to the flow "
                    "speed, exceeds at rest (docs/validation.md, the deep tank); a weakly compressible "
                    "step (dt <= cfl h / c) never reaches a cap of 0.15",
                ),
                "hydrostatic_start": Key(
                    "bool",
                    True,
                    doc="start each block compressed along gravity to "
                    "its hydrostatic density rho(rho0 |g| depth below the block's top), "
                    "so that a resting pool starts in equilibrium instead of ringing (with levels, "
                    "after the start's splits, so that fine particles sit where a uniform start puts "
                    "them); false = uniform lattice at rho0",
                ),
                "settle": Key(
                    "float",
                    0.0,
                    "[0, 10]",
                    "s",
                    "before t = 0, run the fluid this long with every velocity damped "
                    "(fluid.settle_damping), then start the clock at 0: a pool whose seeded "
                    "lattice is not the discrete equilibrium (a 3D cubic lattice under its own weight "
                    "rearranges; so does a level interface) starts at rest instead of ringing in its "
                    "first acoustic mode, which the viscosities hardly damp; 0 = none. Not with "
                    "emitters or stirrers, which have no time before 0",
                ),
                "settle_damping": Key(
                    "float",
                    100.0,
                    "> 0",
                    "1/s",
                    "rate r at which fluid.settle damps: each step multiplies every velocity by "
                    "exp(-r dt). Near the first acoustic mode's angular frequency, pi sqrt(k) / (2 H) "
                    "for a pool H deep (110/s in the deep tanks), it damps that mode within a few periods",
                ),
                "blocks": Array(
                    Table(
                        {
                            "min": Key("vec", unit="m", doc="lower corner"),
                            "max": Key("vec", unit="m", doc="upper corner, > min in every component"),
                            "velocity": Key("vec", unit="m/s", doc="initial velocity", **ZEROS),
                        }
                    ),
                    doc="Boxes of fluid at t = 0: a lattice of spacing s0, or in an adaptive scene "
                    "the coarsest level's lattice where its whole cells fit and finer ones in the "
                    "slabs left over (the same fluid as the uniform run; a block whose sides "
                    "are all whole multiples of the coarsest spacing starts coarse everywhere). "
                    "At least one, unless there is an emitter.",
                ),
            },
        ),
        **SOLVER_TABLES,
        "physics": Table(
            {
                "gravity": Key(
                    "vec",
                    lambda dim: (0.0, -9.81, 0.0)[:dim],
                    unit="m/s^2",
                    doc="gravitational acceleration",
                    default_doc="(0, -9.81[, 0])",
                ),
                "cfl": Key("float", 0.2, "(0, 1]", doc="lambda of the CFL bound dt <= lambda h / (c_s + max |u|)"),
                "force_factor": Key(
                    "float", 0.25, "(0, 1]", doc="lambda_f of the force bound dt <= lambda_f sqrt(h / max |a|)"
                ),
                "viscous_factor": Key(
                    "float",
                    0.03,
                    "(0, 1]",
                    doc="lambda_v of the viscous bound dt <= lambda_v h0^2 rho0 / mu (h0 the finest support)",
                ),
                "dt_max": Key("float", 0.002, "> 0", "s", "largest time step"),
                "dt_min": Key("float", 1e-7, "> 0", "s", "a step needing less is reported as unstable; < dt_max"),
                "max_speed": Key(
                    "float",
                    250.0,
                    "> 0",
                    "m/s",
                    "a faster particle is reported as a "
                    "blow-up (the app's strongest stirring, tools/soak.py, asks for up to 80 "
                    "m/s; its fastest particle reached 31 m/s with wcsph, 107 with dfsph)",
                ),
            }
        ),
        "obstacles": Array(
            Table({"shape": SHAPE}, switch="shape", variants=SHAPES),
            doc=f"Static solid shapes, at most {MAX_OBSTACLES} of each shape. The keys of the other shape are unknown. "
            "A box's face on or past a wall of the domain (a post standing on the floor) is shut: "
            "fluid pushed into the box leaves it by another face.",
        ),
        "emitters": Array(
            Table(
                {
                    "center": Key("vec", unit="m", doc="centre of the emitting disc (segment in 2D)"),
                    "radius": Key("float", range="> 0", unit="m", doc="half-width of the disc"),
                    "velocity": Key(
                        "vec", unit="m/s", doc="velocity of emitted fluid, non-zero; the disc faces along it"
                    ),
                    "start": Key("float", 0.0, ">= 0", "s", "time emission starts"),
                    "stop": Key("float", 1e9, "> 0", "s", "time emission stops, > start"),
                    "level": Key("int", 0, ">= 0", doc="level of emitted particles, < adaptivity.levels"),
                }
            ),
            doc="Inflows that add fluid while the simulation runs. Each has a nozzle: while it "
            "emits, fluid within one support of its disc (of the emitted level; ahead or behind, "
            "within the radius plus half a spacing) moves at its velocity, as in a hose's pipe.",
        ),
        "adaptivity": Table(
            {
                "enabled": Key("bool", False, doc="split and merge particles between levels"),
                "levels": Key("int", 1, "[1, 6]", doc="number of levels L; >= 2 when enabled"),
                "interval": Key("int", 4, ">= 1", doc="steps between adaptivity passes"),
                "hysteresis": Key(
                    "float", 0.25, "[0, 0.5)", doc="gap between split and merge thresholds, in level units"
                ),
                "band": Key(
                    "float",
                    0.0,
                    ">= 0",
                    "m",
                    "width of the distance band per level; 0 = automatic: 2 h_(L-1), twice the coarsest support radius",
                ),
                "coupling": Key(
                    "choice",
                    "variational",
                    choices=("variational", "symmetric"),
                    doc="how real and virtual particles exchange forces: variational = "
                    "virtual particles carry their owners' mass, density and velocity and "
                    "a real–virtual pressure force uses the real particle's pressure only "
                    "(each particle's pressure acts once, on its own level; energy-"
                    "consistent); symmetric = the thesis's same-level symmetric pair "
                    "force with virtual particles' own summed density and interpolated "
                    "velocity (docs/METHOD.md §13)",
                ),
                "spring_rate": Key(
                    "float",
                    100000.0,
                    ">= 0",
                    "1/s",
                    "rate at which the Hooke springs "
                    "return virtual particles to their anchors, integrated implicitly "
                    "(rate * dt >= 1 puts them on the anchor: the default does so for "
                    "any dt >= 1e-5 s); loose springs let the interface drift and gain "
                    "energy",
                ),
                "release_factor": Key(
                    "float",
                    1.0,
                    "[0.5, 2]",
                    doc="siblings are released when their largest distance exceeds release_factor * h_n",
                ),
                "merge_min_children": Key(
                    "int",
                    0,
                    ">= 0",
                    doc="least group size that merges once "
                    "no neighbouring group can join it (a full group of 2^dim "
                    "always merges); 0 = 2^(dim-1), one layer of the coarse "
                    "cell, so that a film one fine particle thick can coarsen; "
                    "<= 2^dim",
                ),
                "merge_remnants": Key(
                    "bool",
                    False,
                    doc="a group smaller than merge_min_children "
                    "merges too where it sits among coarse particles (a real "
                    "coarse particle within its virtual parent's support) and no "
                    "group can join it, down to 2^-dim of the nominal mass; false = "
                    "such remnants stay fine (and keep the time step fine)",
                ),
                "absorb_below": Key(
                    "float",
                    0.5,
                    "[0, 1]",
                    doc="a group that would merge into a "
                    "particle lighter than this share of its level's nominal mass is "
                    "given instead to the nearest real particle of that level (of any "
                    "kind) within half its support (its mass and momentum; it keeps its place and "
                    "within 2x nominal), or stays fine where there is none; so no "
                    "particle falls below half its level's mass through repeated "
                    "splits and merges; 0 = such groups merge",
                ),
                "gather_factor": Key(
                    "float", 1.0, "(0, 2]", doc="virtual parents closer than gather_factor * coarse spacing may gather"
                ),
                "gather_span": Key(
                    "float",
                    0.9,
                    "(0, 1)",
                    doc="a gathered group spans at most "
                    "gather_span * the release distance, so that it is not released "
                    "at the next pass and gathered again; above sqrt(dim)/2 (0.87 in "
                    "3D) so that a lattice cell of 2^dim fine particles can gather",
                ),
                "background_level": Key(
                    "int", -1, ">= -1", doc="level wanted where no criterion asks for finer; -1 = L-1, the coarsest"
                ),
                "limit_virtual_density": Key(
                    "bool",
                    True,
                    doc="scale down the masses of virtual "
                    "children where they would raise a real particle's "
                    "density above that of the coarse particles they stand "
                    "for (their fixed lattices overlap where coarse "
                    "particles are closer than their spacing); false = "
                    "always 2^-d of the parent's mass",
                ),
                "virtual_density_tolerance": Key(
                    "float",
                    0.03,
                    "[0, 1]",
                    doc="how far above the "
                    "coarse particles' density (and never below rho0) "
                    "the limiter lets virtual children raise a real "
                    "particle's density; 0 = not at all, which in a "
                    "resting pool cuts virtual masses at every small "
                    "overlap and stirs the interface",
                ),
                "gather_coarse_only": Key(
                    "bool",
                    True,
                    doc="virtual parents gather only where the "
                    "criteria want the coarse level (wanted level > c), where "
                    "their groups may go on to merge; false = anywhere in the "
                    "transition layer (each gather moves mass at the coarse "
                    "level and stirs a resting interface)",
                ),
                "split_relax": Key(
                    "choice",
                    "spacing",
                    choices=("spacing", "density"),
                    doc="how the children of a split leave their parent's lattice "
                    "cell, velocities unchanged: spacing = each is pushed "
                    "split_min_distance away from its real neighbours; density = "
                    "each moves down the gradient of its level's density until it "
                    "reads no more than its parent's (rho0 at least). With two "
                    "levels density stops the splits of a thin sheet from throwing "
                    "fluid; with a third, coarser level it threw more (docs/METHOD.md "
                    "§12, and docs/validation.md, \"The first splits of a dam break\")",
                ),
                "split_density_tolerance": Key(
                    "float",
                    0.01,
                    "[0, 0.1]",
                    doc="with split_relax = "
                    "density: how far above its parent's density (and "
                    "rho0), as a fraction, a new child may read before it "
                    "is moved; 0 = not at all, which also moves the "
                    "children of splits in a resting pool and stirs it; "
                    "larger lets more of the split's compression through "
                    "(docs/validation.md, \"The first splits of a dam break\")",
                ),
                "split_relax_iterations": Key(
                    "int", 8, ">= 0", doc="iterations of split_relax; 0 = children stay on the lattice"
                ),
                "split_min_distance": Key(
                    "float",
                    1.0,
                    "(0, 2]",
                    doc="with split_relax = spacing: "
                    "the distance, in spacings of the children's level, that "
                    "the iterations open between a new child and its real "
                    "neighbours",
                ),
                "split_fade": Key(
                    "float",
                    0.0,
                    ">= 0",
                    "s",
                    "0 = off. Else the density a split's child "
                    "reads above its parent's (rho0 at least) at its first density pass "
                    "is left out of its pressure, following the child's density down "
                    "as the children spread and decaying as exp(-t/tau) at most, so "
                    "that a split's sampling error does not act as a compression. The "
                    "demos set 1 s: without it a cursor entering resting water threw it "
                    "about; off by default, since it ran the 3D dam-break front refined "
                    "near a block 7-23 % ahead of the uniform run's, against +1.6 % "
                    "(multires/fade.py)",
                ),
                "split_near_regular": Key(
                    "bool",
                    False,
                    doc="also split a transient parent that "
                    "has a regular particle of the finer level within its "
                    "support, where the criteria do not want it merged "
                    "(METHOD.md 5.2's other trigger)",
                ),
            }
        ),
        "criteria": Array(
            Table(
                {
                    "type": Key(
                        "choice", choices=("region", "obstacles", "disturbance"), doc="what wants the finer level"
                    ),
                    "level": Key("int", 0, ">= 0", doc="level wanted inside, < adaptivity.levels"),
                },
                switch="type",
                variants={
                    "region": Table(
                        {
                            "shape": SHAPE,
                            "path": Key(
                                "path",
                                None,
                                min_items=1,
                                doc="waypoints [t, x, y(, z)]; the region moves by (waypoint at t) - (first waypoint)",
                            ),
                            "loop": Key("bool", False, doc="repeat the path"),
                        },
                        switch="shape",
                        variants=SHAPES,
                    ),
                    "obstacles": Table(
                        {
                            "distance": Key(
                                "float", 0.0, ">= 0", "m", "the level is wanted within this distance of an obstacle"
                            )
                        }
                    ),
                    "disturbance": Table({}, doc="Refines where the mouse or a stirrer acts."),
                },
            ),
            doc=f"Refinement criteria: where finer levels are wanted. The finest wins. At most {MAX_CRITERIA}.",
            max_items=MAX_CRITERIA,
        ),
        "stirrers": Array(
            Table(
                {
                    "radius": Key("float", range="> 0", unit="m", doc="radius of action"),
                    "strength": Key(
                        "float",
                        range=">= 0",
                        unit="1/s",
                        doc="rate at which fluid in the radius is driven toward the stirrer's velocity",
                    ),
                    "mode": Key(
                        "choice",
                        "push",
                        choices=("push", "pull"),
                        doc="push drives the fluid "
                        "in the radius toward the stirrer's own velocity (a moving stirrer drags it "
                        "along, a still one brakes it); pull draws it toward the centre",
                    ),
                    "path": Key("path", min_items=2, doc="waypoints [t, x, y(, z)] with increasing t"),
                    "loop": Key("bool", True, doc="repeat the path"),
                }
            ),
            doc=f"Scripted disturbances for headless runs; at most {MAX_STIRRERS} (the mouse's is one more).",
            max_items=MAX_STIRRERS,
        ),
        "run": Table(
            {
                "fps": Key(
                    "float",
                    30.0,
                    f"[{FPS_RANGE[0]:g}, {FPS_RANGE[1]:g}]",
                    "1/s",
                    "frames rendered or dumped per simulated second",
                ),
                "frames": Key("int", 0, ">= 0", doc="frames of a headless run; 0 = none given"),
            }
        ),
        "render": Table(
            {
                "width": Key("int", 960, "[64, 8192]", "px", "image width"),
                "height": Key("int", 540, "[64, 8192]", "px", "image height"),
                "background": Key("vec3", (0.07, 0.08, 0.1), "[0, 1]", doc="RGB background colour"),
                "camera_position": Key("vec3", None, unit="m", doc="3D only; omitted = automatic"),
                "camera_lookat": Key("vec3", None, unit="m", doc="3D only; omitted = automatic"),
                "point_scale": Key("float", 1.0, "> 0", doc="scale of drawn particle radii"),
                "surface": Key(
                    "bool",
                    False,
                    doc="water view: the fluid drawn as a surface (2D: a "
                    "filled area tinted by the particles' colours; 3D: a lit mesh) in the "
                    "window (key w toggles it) and in recordings",
                ),
            }
        ),
    },
)


def default_of(dotted: str, dim: int = 2):
    """The schema's default of a scalar key (``"render.width"``), None where it has none
    (required, optional, or not a key of a table): what a reader of a plain-dict scene
    (the app's stand-in) falls back on, so that no default is written twice."""
    node = SCHEMA
    *tables, last = dotted.split(".")
    for name in tables:
        node = node.keys.get(name) if isinstance(node, Table) else None
        if node is None and name in SOLVER_TABLES:
            node = SOLVER_TABLES[name]
    key = node.keys.get(last) if isinstance(node, Table) else None
    if not isinstance(key, Key) or key.default is REQUIRED:
        return None
    return key.default(dim) if callable(key.default) else key.default
