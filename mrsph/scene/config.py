"""Scene files: strict, typed TOML with every problem reported at once.

A scene is a TOML file in ``scenes/``; docs/scenes.md lists every key (type, unit,
default, meaning). ``load_scene`` parses it, applies ``--set KEY=VALUE`` overrides,
checks each key against ``SCHEMA`` (type, range, vector length, unknown keys with a
did-you-mean hint), then the cross-field rules (fluid inside the domain and outside the
obstacles, levels that exist, a capacity that holds the fluid), and raises one
``SceneError`` holding all problems, one line each:
``<file>: <key>: <what is wrong> (got <value>; expected <what>)``.
Pure Python, no Taichi, nothing done at import.
"""

from __future__ import annotations

import copy
import difflib
import json
import math
import numbers
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mrsph.limits import (
    FPS_RANGE,
    LATTICE_EPS,
    MAX_CAPACITY,
    MAX_CRITERIA,
    MAX_GRID_CELLS,
    MAX_OBSTACLES,
    MAX_STIRRERS,
)

# The scene files: the checkout's scenes/ at the repository's root, or, in an installed
# package (pip install .), the copy pyproject.toml puts in mrsph/scenes.
_PACKAGE = Path(__file__).resolve().parents[1]
SCENES_DIR = next(
    (d for d in (_PACKAGE.parent / "scenes", _PACKAGE / "scenes") if d.is_dir()), _PACKAGE.parent / "scenes"
)

REQUIRED = object()  # default of a key that the scene must give

# Automatic capacity = int(CAPACITY_MARGIN * lattice + emitted) + CAPACITY_SLACK: splits
# turn one particle into 2^d and virtual particles need slots too, hence the margin.
CAPACITY_MARGIN = 1.5
CAPACITY_SLACK = 1024
# An emitter counts for at most this long when sizing automatic capacity (its default
# stop time of 1e9 s would otherwise ask for unbounded memory).
EMIT_HORIZON_S = 60.0


class SceneError(Exception):
    """Everything wrong with a scene; ``problems`` has one line per problem."""

    def __init__(self, problems: list[str] | str):
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        super().__init__("\n".join(self.problems))


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
                "capacity": Key(
                    "int",
                    0,
                    ">= 0",
                    doc=f"particle slots, at most "
                    f"{MAX_CAPACITY[2] // 10**6} million (2D) or {MAX_CAPACITY[3] // 10**6} "
                    "million (3D); 0 = automatic: "
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
                    "wcsph",
                    choices=("wcsph", "dfsph"),
                    doc="pressure solver "
                    "(mrsph/pressure/): wcsph, weakly compressible, pressure from the equation of "
                    "state fluid.eos, time step tied to the sound speed sqrt(fluid.stiffness); "
                    "dfsph, divergence-free SPH (Bender & Koschier 2015), implicit, time step "
                    "tied to the flow speed (keys in [dfsph])",
                ),
                "eos": Key(
                    "choice",
                    "linear",
                    choices=("linear", "tait"),
                    doc="equation of state: "
                    "linear p = k (rho - rho0); tait p = rho0 k / gamma ((rho/rho0)^gamma - 1); "
                    "both have sound speed sqrt(k) at rest",
                ),
                "stiffness": Key("float", 1000.0, "> 0", "m^2/s^2", "k, the squared sound speed"),
                "gamma": Key("float", 7.0, "[1, 10]", doc="exponent of the Tait equation"),
                "clamp_negative_pressure": Key(
                    "bool", True, doc="clamp pressure at 0 (no clumping at the free surface)"
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
                "hydrostatic_start": Key(
                    "bool",
                    True,
                    doc="start each block compressed along gravity to "
                    "its hydrostatic density rho(rho0 |g| depth below the block's top), "
                    "so that a resting pool starts in equilibrium instead of ringing; "
                    "false = uniform lattice at rho0",
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
        "dfsph": Table(
            {
                "cfl": Key(
                    "float",
                    0.4,
                    "(0, 1]",
                    doc="lambda of the CFL bound dt <= lambda s / max |u| "
                    "(s the particle's level spacing): a particle moves at most lambda spacings a step",
                ),
                "density_tolerance": Key(
                    "float",
                    0.001,
                    "> 0",
                    doc="the density solve stops when the average "
                    "predicted compression (rho* - rho0)/rho0 of the real particles is "
                    "within this (0.001 = 0.1 %)",
                ),
                "rest_tolerance": Key(
                    "float",
                    0.0005,
                    "> 0",
                    doc="the tightest the density tolerance "
                    "gets: in a slow flow (slow_flow) density_tolerance is scaled by "
                    "how slow, down to this. The compression a solve leaves is undone "
                    "the next step at about tolerance s/dt, a noise of its own in water "
                    "at rest (the resting 3D tank moved at 1.3 % of sqrt(gH) "
                    "unscaled, 0.8 % at 0.0005); = density_tolerance: unscaled",
                ),
                "slow_flow": Key(
                    "float",
                    0.1,
                    "(0, 1]",
                    doc="a step in which the fastest particle moves "
                    "less than this share of its spacing is a slow flow: the density "
                    "tolerance is scaled by max |u| dt / s over this (see rest_tolerance)",
                ),
                "max_density_error": Key(
                    "float",
                    0.01,
                    "> 0",
                    doc="and until no real particle's predicted "
                    "compression is above this (0.01 = 1 %): a hot spot of a few dozen "
                    "particles hides in the average (docs/performance.md, the stirred "
                    "soak); larger is faster",
                ),
                "divergence_tolerance": Key(
                    "float",
                    0.01,
                    "> 0",
                    doc="the divergence solve stops when the "
                    "average density rate of change times dt, over rho0, is within this",
                ),
                "min_iterations": Key("int", 1, ">= 0", doc="velocity updates of the density solve at least"),
                "max_iterations": Key(
                    "int",
                    100,
                    ">= 1",
                    doc="velocity updates of the density solve at most; "
                    "a solve that stops here is counted in stats (unconverged) and warned once",
                ),
                "divergence_min_iterations": Key(
                    "int", 0, ">= 0", doc="velocity updates of the divergence solve at least"
                ),
                "divergence_max_iterations": Key(
                    "int",
                    100,
                    ">= 1",
                    doc="velocity updates of the divergence solve at most (counted and warned as max_iterations)",
                ),
                "divergence_solve": Key(
                    "bool",
                    True,
                    doc="run the divergence solve each step (false: the density solve alone, as IISPH-like schemes)",
                ),
                "warm_start": Key(
                    "float",
                    0.5,
                    "[0, 1]",
                    doc="the share of the last step's pressure the "
                    "density solve starts from, where the kicked fluid is compressed (0: a "
                    "cold start; 1, the whole, ratchets the 2D dam break's pressure up until "
                    "it blows up)",
                ),
            },
            doc="The divergence-free solver (fluid.solver = \"dfsph\"); ignored by wcsph.",
        ),
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
            doc=f"Static solid shapes, at most {MAX_OBSTACLES} of each shape. The keys of the other shape are unknown.",
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
                    "velocity (see docs/research-log.md)",
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
                    "fluid; with a third, coarser level it threw more (see the "
                    "table of choices in docs/research-log.md)",
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
                    "(see docs/research-log.md)",
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


# ----------------------------------------------------------------------------- values
def _is_num(x) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool)


def _in_range(x: float, rng: str) -> bool:
    if not rng:
        return True
    if rng[0] in "[(":
        lo, hi = (float(s) for s in rng[1:-1].split(","))
        return (lo < x if rng[0] == "(" else lo <= x) and (x < hi if rng[-1] == ")" else x <= hi)
    op, bound = rng.split()
    return x > float(bound) if op == ">" else x >= float(bound)


_TYPE_NAMES = {
    bool: "boolean",
    int: "integer",
    float: "float",
    str: "string",
    list: "array",
    tuple: "array",
    dict: "table",
}


def _fmt(v, typed: bool = False) -> str:
    """A value as TOML writes it, shortened; ``typed`` appends its TOML type."""
    if isinstance(v, bool):
        s = "true" if v else "false"
    elif isinstance(v, str):
        s = json.dumps(v)
    elif isinstance(v, (list, tuple)):
        s = "[" + ", ".join(_fmt(x) for x in v) + "]"
    elif isinstance(v, dict):
        s = "{" + ", ".join(f"{k} = {_fmt(x)}" for k, x in v.items()) + "}"
    else:
        s = repr(v)
    s = s if len(s) <= 80 else s[:77] + "..."
    return f"{s} ({_TYPE_NAMES.get(type(v), type(v).__name__)})" if typed else s


def _expected(k: Key, dim: int | None) -> str:
    rng = ("in " + k.range if k.range[:1] in "[(" else k.range) if k.range else ""
    coords = "x, y" if dim == 2 else "x, y, z" if dim == 3 else "x, y(, z)"
    base = {
        "float": "a number",
        "int": "an integer",
        "bool": "true or false",
        "str": "a one-line string",
        "vec": f"a list of {dim or 'dim'} numbers",
        "vec3": "a list of 3 numbers",
        "choice": "one of " + ", ".join(json.dumps(c) for c in k.choices),
        "path": f"a list of >= {k.min_items} waypoints [t, {coords}] with strictly increasing t",
    }[k.kind]
    return f"{base} {rng}".strip()


class _Bad(Exception):
    def __init__(self, what: str, typed: bool = False):
        self.what, self.typed = what, typed


def _convert(k: Key, v, dim: int | None):
    """``v`` checked against ``k`` and normalised (floats, tuples), or raise _Bad."""
    v = v.tolist() if hasattr(v, "tolist") else v  # numpy scalars and arrays
    if k.kind in ("float", "int"):
        if not _is_num(v) or (k.kind == "int" and not isinstance(v, numbers.Integral)):
            raise _Bad("wrong type", typed=True)
        if not math.isfinite(v):
            raise _Bad("not finite")
        if not _in_range(v, k.range):
            raise _Bad("out of range")
        return float(v) if k.kind == "float" else v
    if k.kind == "bool":
        if not isinstance(v, bool):
            raise _Bad("wrong type", typed=True)
        return v
    if k.kind in ("str", "choice"):
        if not isinstance(v, str):
            raise _Bad("wrong type", typed=True)
        if k.kind == "str" and "\n" in v:
            raise _Bad("not one line")
        if k.kind == "choice" and v not in k.choices:
            hint = difflib.get_close_matches(v, k.choices, 1)
            raise _Bad("unknown choice" + (f", did you mean '{hint[0]}'?" if hint else ""))
        return v
    if k.kind in ("vec", "vec3"):
        n = 3 if k.kind == "vec3" else dim
        if not isinstance(v, (list, tuple)) or not all(_is_num(c) for c in v):
            raise _Bad("wrong type", typed=True)
        if n is not None and len(v) != n:
            raise _Bad("wrong length")
        if not all(math.isfinite(c) for c in v):
            raise _Bad("not finite")
        if not all(_in_range(c, k.range) for c in v):
            raise _Bad("out of range")
        return tuple(float(c) for c in v)
    # a path: waypoints [t, x, y(, z)]
    if not isinstance(v, (list, tuple)) or not all(
        isinstance(w, (list, tuple)) and all(_is_num(c) for c in w) for w in v
    ):
        raise _Bad("wrong type", typed=True)
    if len(v) < k.min_items:
        raise _Bad("too few waypoints")
    if dim is not None and any(len(w) != dim + 1 for w in v):
        raise _Bad("waypoint of the wrong length")
    if not all(math.isfinite(c) for w in v for c in w):
        raise _Bad("not finite")
    if any(b[0] <= a[0] for a, b in zip(v, v[1:])):
        raise _Bad("waypoint times not strictly increasing")
    return tuple(tuple(float(c) for c in w) for w in v)


def _all_keys(t: Table) -> dict:
    """Every key a table may hold, whatever its variant."""
    keys = dict(t.keys)
    for variant in t.variants.values():
        keys.update(_all_keys(variant))
    return keys


def _hint(name: str, candidates) -> str:
    close = difflib.get_close_matches(name, list(candidates), 1)
    if close:
        return f"did you mean '{close[0]}'?"
    return "expected one of " + ", ".join(f"'{c}'" for c in candidates)


# ------------------------------------------------------------------------- validation
#: how problems name an override given as "KEY=VALUE" text, as the command line does
OPTION_FLAG = "--set"


class _Checker:
    def __init__(self, label: str, overridden: list[str], flag: str = OPTION_FLAG):
        self.label, self.overridden, self.problems = label, overridden, []
        self.flag = flag  # how overrides are named: "--set", or "override" from Python
        self.broken: set[str] = set()  # keys already reported as bad (arrays read as empty)

    def add(self, key: str, what: str, got: str = "", expected: str = "", note: str = ""):
        detail = note or "; ".join(s for s in (got and "got " + got, expected and "expected " + expected) if s)
        # a problem in a value given with --set is reported under that label; one that a
        # --set may have caused elsewhere (a spacing that leaves a block empty) says so
        label = self.label
        if self.overridden:
            label += f" with {self.flag} {', '.join(self.overridden)}"
        # a key inside a table or array given whole (--set physics={cfl=5}) is named in full
        where = next(
            (
                f"{self.flag} {o}" + ("" if key == o else f": {key}")
                for o in self.overridden
                if key == o or key.startswith(o + ".")
            ),
            f"{label}: {key}",
        )
        self.problems.append(f"{where}: {what}" + (f" ({detail})" if detail else ""))

    def table(self, spec: Table, raw, key: str, dim):
        if not isinstance(raw, dict):
            self.add(key, "wrong type", _fmt(raw, True), "a table")
            return None
        out: dict = {}
        allowed = self.fill(spec, raw, key, dim, out)
        for name in raw:
            if allowed is not None and name not in allowed:
                self.add(f"{key}.{name}" if key else name, "unknown key", note=_hint(name, sorted(allowed)))
        lo, hi = out.get("min"), out.get("max")
        if lo is not None and hi is not None and any(b <= a for a, b in zip(lo, hi)):
            self.add(f"{key}.max", "not above min", _fmt(hi), f"every component > min = {_fmt(lo)}")
            out["max"] = None  # so that the cross-field rules skip this box
        return out

    def fill(self, spec: Table, raw: dict, key: str, dim, out: dict):
        """Check the keys of ``spec`` (and its chosen variant); return the allowed names."""
        for name, sub in spec.keys.items():
            k = f"{key}.{name}" if key else name
            if isinstance(sub, Table):
                if name not in raw and sub.required:
                    self.add(k, "missing required key", expected=f"a table [{k}]")
                    out[name] = None
                else:
                    out[name] = self.table(sub, raw.get(name, {}), k, dim)
            elif isinstance(sub, Array):
                items = raw.get(name, [])
                if not isinstance(items, (list, tuple)):
                    self.add(k, "wrong type", _fmt(items, True), f"an array of tables [[{k}]]")
                    self.broken.add(k)
                    items = []
                if sub.max_items and len(items) > sub.max_items:
                    self.add(k, "too many entries", str(len(items)), f"at most {sub.max_items}")
                out[name] = [self.table(sub.item, item, f"{k}.{i}", dim) for i, item in enumerate(items)]
            elif name in raw:
                try:
                    out[name] = _convert(sub, raw[name], dim)
                except _Bad as bad:
                    self.add(k, bad.what, _fmt(raw[name], bad.typed), _expected(sub, dim))
                    out[name] = None
                    self.broken.add(k)
            elif sub.default is REQUIRED:
                self.add(k, "missing required key", expected=_expected(sub, dim))
                out[name] = None
            else:
                out[name] = sub.default(dim) if callable(sub.default) and dim else sub.default
        allowed = set(spec.keys)
        if spec.switch:
            variant = spec.variants.get(out.get(spec.switch))
            if variant is None:
                return None  # the switch itself is reported; other keys cannot be judged
            inner = self.fill(variant, raw, key, dim, out)  # None: its own switch is bad
            return None if inner is None else allowed | inner
        return allowed


def _lattice_count(blocks: list[dict], s0: float) -> int:
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


def _ok(*values) -> bool:
    return all(v is not None for v in values)


def _block_ok(b) -> bool:
    return bool(b) and _ok(b["min"], b["max"])


def _overlap(b: dict, ob: dict) -> str | None:
    """How obstacle ``ob`` is described if fluid block ``b`` overlaps it, else None."""
    if ob["shape"] == "box" and _ok(ob["min"], ob["max"]):
        pairs = zip(b["min"], b["max"], ob["min"], ob["max"])
        if all(a0 < b1 and b0 < a1 for a0, a1, b0, b1 in pairs):
            return f"the box {_fmt(ob['min'])} .. {_fmt(ob['max'])}"
    elif ob["shape"] == "sphere" and _ok(ob["center"], ob["radius"]):
        # squared distance from the centre to the nearest point of the block
        d2 = sum((c - min(max(c, a), b)) ** 2 for a, b, c in zip(b["min"], b["max"], ob["center"]))
        if d2 < ob["radius"] ** 2:
            return f"the sphere at {_fmt(ob['center'])} with radius {ob['radius']!r}"
    return None


def _check_places(c: _Checker, d: dict) -> None:
    """Fluid, emitters and regions inside the domain; fluid outside the obstacles."""
    dom, fluid, emitters = d["domain"], d["fluid"], d["emitters"]
    blocks = [(i, b) for i, b in enumerate(fluid["blocks"] if fluid else []) if _block_ok(b)]
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
        if _ok(spacing) and spacing > 0:
            thin = [k for k, (lo, hi) in enumerate(zip(b["min"], b["max"])) if hi - lo < spacing * (1.0 - LATTICE_EPS)]
            if thin:
                c.add(
                    f"fluid.blocks.{i}",
                    "holds no particle",
                    f"min {_fmt(b['min'])}, max {_fmt(b['max'])}",
                    f"at least particles.spacing = {_fmt(spacing)} m across on every axis (not on axis {thin[0]})",
                )
        for j, ob in enumerate(d["obstacles"]):
            what = ob and _overlap(b, ob)
            if what:
                c.add(
                    f"fluid.blocks.{i}",
                    f"overlaps obstacles.{j}",
                    f"min {_fmt(b['min'])}, max {_fmt(b['max'])}",
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
                    f"min {_fmt(b['min'])}, max {_fmt(b['max'])}",
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
    if not (dom and _ok(dom["min"], dom["max"])):
        return
    where = f"inside the domain {_fmt(dom['min'])} .. {_fmt(dom['max'])}"

    def inside(p) -> bool:
        return _in_box(p, dom["min"], dom["max"])

    for i, b in blocks:
        if not (inside(b["min"]) and inside(b["max"])):
            c.add(f"fluid.blocks.{i}", "outside the domain", f"min {_fmt(b['min'])}, max {_fmt(b['max'])}", where)
    for i, e in enumerate(emitters):
        if e and e["center"] is not None and not inside(e["center"]):
            c.add(f"emitters.{i}.center", "outside the domain", _fmt(e["center"]), where)
    for i, st in enumerate(d["stirrers"]):
        away = [w for w in (st and st["path"] or []) if not inside(w[1:])]
        if away:
            c.add(
                f"stirrers.{i}.path",
                "waypoint outside the domain",
                _fmt(list(away[0])),
                f"every waypoint's position {where}",
            )
    for i, cr in enumerate(d["criteria"]):
        if not (cr and cr["type"] == "region" and cr["shape"] in SHAPES):
            continue
        if cr["shape"] == "sphere":
            center = cr["center"]
        else:
            center = _block_ok(cr) and tuple((a + b) / 2 for a, b in zip(cr["min"], cr["max"]))
        if center and not inside(center):
            c.add(f"criteria.{i}", "region centre outside the domain", _fmt(center), where)


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


def _check_emitters(c: _Checker, d: dict) -> None:
    """Every point an emitter places lies in the domain and outside every obstacle (a
    particle placed inside a solid is thrown out of it at many times the emitter's speed)."""
    dom, part, ad = d["domain"], d.get("particles") or {}, d["adaptivity"] or {}
    if not (dom and _ok(dom["min"], dom["max"]) and _ok(part.get("spacing"))):
        return
    for i, e in enumerate(d["emitters"]):
        if not (
            e
            and _ok(e["center"], e["radius"], e["velocity"], e["level"])
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
                f"centre {_fmt(e['center'])}, radius {e['radius']!r}",
                f"a disc inside the domain {_fmt(dom['min'])} .. {_fmt(dom['max'])} "
                f"(its point {_fmt([round(float(x), 6) for x in outside[0]])} is not)",
            )
        for j, ob in enumerate(d["obstacles"]):
            valid = ob and (_block_ok(ob) if ob["shape"] == "box" else _ok(ob["center"], ob["radius"]))
            if valid and any(_inside_obstacle(p, ob) for p in pts):
                c.add(
                    f"emitters.{i}",
                    f"outlet inside obstacles.{j}",
                    f"centre {_fmt(e['center'])}, radius {e['radius']!r}",
                    f"a disc clear of the {ob['shape']} obstacles.{j}",
                )


def _check_values(c: _Checker, d: dict) -> None:
    """Rules between two keys of one table."""
    for i, e in enumerate(d["emitters"]):
        if e and e["velocity"] is not None and not any(e["velocity"]):
            c.add(
                f"emitters.{i}.velocity",
                "zero velocity",
                _fmt(e["velocity"]),
                "a non-zero vector; the emitting disc faces along it",
            )
        if e and _ok(e["start"], e["stop"]) and e["stop"] <= e["start"]:
            c.add(f"emitters.{i}.stop", "not after start", _fmt(e["stop"]), f"a number > start = {e['start']!r}")
    fl, ad = d["fluid"], d["adaptivity"]
    if fl and ad and fl["solver"] == "dfsph" and ad["enabled"] and ad["coupling"] == "symmetric":
        c.add(
            "adaptivity.coupling",
            "not with fluid.solver = \"dfsph\"",
            _fmt(ad["coupling"]),
            "\"variational\" (the implicit solver hands a virtual particle's reaction to its "
            "owners and takes its velocity from them)",
        )
    phys = d["physics"]
    if phys and _ok(phys["dt_min"], phys["dt_max"]) and phys["dt_min"] >= phys["dt_max"]:
        c.add("physics.dt_min", "not below dt_max", _fmt(phys["dt_min"]), f"a number < dt_max = {phys['dt_max']!r}")
    for name in ("camera_position", "camera_lookat"):
        if d["dim"] == 2 and d["render"] and d["render"][name] is not None:
            c.add(f"render.{name}", "only for 3D scenes", _fmt(d["render"][name]), "no camera keys when dim = 2")


def _check_levels(c: _Checker, d: dict) -> None:
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
        if ad["band"] == 0.0 and part and _ok(part["spacing"], part["support"]):
            ad["band"] = 2 * part["support"] * part["spacing"] * 2 ** (used - 1)
        # a level whose support reaches across the whole domain has no fluid to resolve:
        # its few particles see mostly their own mirror images
        if used > 1 and part and dom and _ok(part["spacing"], part["support"], dom["min"], dom["max"]):
            side = min(b - a for a, b in zip(dom["min"], dom["max"]))
            h0 = part["support"] * part["spacing"]
            if h0 * 2 ** (used - 1) > side:
                fit = max(1, int(math.floor(math.log2(side / h0) + 1e-9)) + 1) if side >= h0 else 1
                c.add(
                    "adaptivity.levels",
                    "too many for the domain",
                    str(levels),
                    f"at most {fit}: level {used - 1}'s support radius, "
                    f"{_fmt(h0 * 2 ** (used - 1))} m, exceeds the domain's smallest side, "
                    f"{_fmt(side)} m",
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


def _check_sizes(c: _Checker, d: dict) -> None:
    """The neighbour grid and the particle pool are big enough; resolve capacity 0."""
    dom, part, fluid, emitters = d["domain"], d["particles"], d["fluid"], d["emitters"]
    if not (part and _ok(part["spacing"], part["support"])):
        return
    s0, h0 = part["spacing"], part["spacing"] * part["support"]
    if dom and _ok(dom["min"], dom["max"]):
        cells = math.prod(max(0.0, b - a) / h0 for a, b in zip(dom["min"], dom["max"]))
        if cells > MAX_GRID_CELLS:
            c.add(
                "domain",
                "too large for the neighbour grid",
                f"{cells:.3g} cells of size h0 = {h0:g} m",
                f"<= {MAX_GRID_CELLS:.0e} cells; raise particles.spacing or shrink the domain",
            )
    limit = MAX_CAPACITY[d["dim"]]
    if part["capacity"] is not None and part["capacity"] > limit:
        c.add(
            "particles.capacity",
            "too many slots for the neighbour lists",
            str(part["capacity"]),
            f"<= {limit} in {d['dim']}D",
        )
        return
    if not (fluid and all(_block_ok(b) for b in fluid["blocks"])) or part["capacity"] is None:
        return
    need = _lattice_count(fluid["blocks"], s0)
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


def _check_enabled(c: _Checker, raw: dict) -> None:
    """Criteria or several levels without ``adaptivity.enabled``: the refinement the scene
    describes would silently not happen (enabled defaults to false)."""
    ad = raw.get("adaptivity")
    ad = ad if isinstance(ad, dict) else {}
    if "enabled" in ad:
        return
    given = []
    if isinstance(raw.get("criteria"), list) and raw["criteria"]:
        given.append("[[criteria]]")
    if isinstance(ad.get("levels"), int) and not isinstance(ad["levels"], bool) and ad["levels"] > 1:
        given.append(f"adaptivity.levels = {ad['levels']}")
    if given:
        c.add(
            "adaptivity.enabled",
            "not set",
            " and ".join(given) + " given",
            "adaptivity.enabled = true to refine, or false to run uniform at the finest spacing",
        )


def _validate(raw, label: str, overridden: list[str], flag: str = OPTION_FLAG) -> tuple[dict | None, list[str]]:
    c = _Checker(label, overridden, flag)
    dim = raw.get("dim") if isinstance(raw, dict) else None
    dim = dim if dim in (2, 3) and isinstance(dim, int) and not isinstance(dim, bool) else None
    d = c.table(SCHEMA, raw, "", dim)
    if d is not None and dim is not None:
        for check in (_check_places, _check_values, _check_levels, _check_emitters, _check_sizes):
            check(c, d)
        if not c.problems:  # a forgotten switch, worth a line once the rest is right
            _check_enabled(c, raw)
    return d, c.problems


# -------------------------------------------------------------------------- overrides
def _parse_value(text: str):
    """A --set value as TOML ("0.2", "true", "[1, 2]", '"tait"'); a bare word is a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"] if "\n" not in text else text
    except tomllib.TOMLDecodeError:
        return text


def _parse_overrides(overrides) -> tuple[list[tuple[str, Any]], list[str]]:
    if not overrides:
        return [], []
    if isinstance(overrides, dict):
        return [(k, _parse_value(v) if isinstance(v, str) else v) for k, v in overrides.items()], []
    pairs, problems = [], []
    for item in overrides:
        key, eq, value = item.partition("=")
        if not eq or not key.strip():
            problems.append(
                f"{OPTION_FLAG} {item}: not KEY=VALUE (got {_fmt(item)}; expected for example fluid.viscosity=0.2)"
            )
        else:
            pairs.append((key.strip(), _parse_value(value.strip())))
    return pairs, problems


def _apply(raw: dict, key: str, value, problems: list[str], flag: str = OPTION_FLAG) -> bool:
    """Set ``raw[key]`` for a dotted key ("fluid.blocks.0.max"), checked against SCHEMA."""
    node, spec = raw, SCHEMA
    parts = key.split(".")
    for n, part in enumerate(parts):
        last = n == len(parts) - 1
        if isinstance(spec, Array):
            if not part.isdigit() or int(part) > len(node):
                problems.append(
                    f"{flag} {key}: no such entry (got {part}; expected an index "
                    f"from 0 to {len(node)}, where {len(node)} adds an entry)"
                )
                return False
            index = int(part)
            if index == len(node):
                node.append({})
            if last:
                node[index] = value
                return True
            if not isinstance(node[index], dict):
                node[index] = {}
            node, spec = node[index], spec.item
            continue
        keys = _all_keys(spec)
        if part not in keys:
            problems.append(f"{flag} {key}: unknown key ({_hint(part, keys)})")
            return False
        if last:
            node[part] = value
            return True
        sub = keys[part]
        if isinstance(sub, Key):
            problems.append(f"{flag} {key}: unknown key ({'.'.join(parts[: n + 1])} is a value, not a table)")
            return False
        kind = list if isinstance(sub, Array) else dict
        if not isinstance(node.get(part), kind):
            node[part] = kind()
        node, spec = node[part], sub
    return False


# ------------------------------------------------------------------------------ scene
class Node:
    """Read-only attribute view of a table of a scene: ``scene.fluid.blocks[0].min``."""

    def __init__(self, data: dict, key: str = ""):
        self._data, self._key = data, key

    def __getattr__(self, name: str):
        if name.startswith("_"):
            raise AttributeError(name)
        try:
            return self[name]
        except KeyError as e:
            raise AttributeError(e.args[0]) from None

    def __getitem__(self, name: str):
        if name not in self._data:
            key = f"{self._key}.{name}" if self._key else name
            raise KeyError(f"{key}: no such key ({_hint(name, sorted(self._data))})")
        return _wrap(self._data[name], f"{self._key}.{name}" if self._key else name)

    def __contains__(self, name: str) -> bool:
        return name in self._data

    def __repr__(self) -> str:
        return f"Node({self._key!r}: {_fmt(self._data)})"


def _wrap(value, key: str):
    if isinstance(value, dict):
        return Node(value, key)
    if isinstance(value, list):
        return tuple(_wrap(v, f"{key}.{i}") for i, v in enumerate(value))
    return value


class Scene(Node):
    """A validated scene: ``data`` holds every key, defaults and automatic values filled."""

    def __init__(self, name: str, path: str, data: dict, raw: dict):
        super().__init__(data)
        self.name, self.path, self.data, self._raw = name, path, data, raw

    def get(self, dotted: str):
        """The value at a dotted key ("fluid.viscosity", "fluid.blocks.0.min")."""
        node = self.data
        for part in dotted.split("."):
            if isinstance(node, dict) and part in node:
                node = node[part]
            elif isinstance(node, list) and part.isdigit() and int(part) < len(node):
                node = node[int(part)]
            else:
                hint = f" ({_hint(part, sorted(node))})" if isinstance(node, dict) else ""
                raise KeyError(f"{dotted}: no such key{hint}")
        return node

    def with_overrides(self, overrides) -> Scene:
        """A re-validated copy with overrides applied to the scene as written."""
        return _build(self._raw, self.path, self.name, overrides)

    def estimate_particles(self) -> int:
        """Lattice points (cell centres at spacing s0) inside all fluid blocks."""
        return _lattice_count(self.data["fluid"]["blocks"], self.data["particles"]["spacing"])

    def __repr__(self) -> str:
        return f"Scene({self.name!r}, dim={self.data['dim']}, path={self.path!r})"


def _label(path: str) -> str:
    """How problems name the file: relative to the working directory when inside it."""
    try:
        return Path(path).resolve().relative_to(Path.cwd().resolve()).as_posix()
    except (ValueError, OSError):
        return path


def _build(raw: dict, path: str, name: str, overrides) -> Scene:
    original, raw = raw, copy.deepcopy(raw)
    pairs, problems = _parse_overrides(overrides)
    # overrides from the command line are named as it names them; a dict from Python as such
    flag = "override" if isinstance(overrides, dict) else OPTION_FLAG
    applied = [key for key, value in pairs if _apply(raw, key, value, problems, flag)]
    label = "<dict>" if path == "<dict>" else _label(path)
    data, found = _validate(raw, label, applied, flag)
    if applied and found:
        # a problem the scene has without the --set values too is the scene's own: it is
        # not labelled "with --set ..." (which says an override may have caused it)
        _, own = _validate(copy.deepcopy(original), label, [])
        prefix = f"{label} with {flag} {', '.join(applied)}: "
        found = [
            f"{label}: {f[len(prefix) :]}" if f.startswith(prefix) and f"{label}: {f[len(prefix) :]}" in own else f
            for f in found
        ]
    if problems or found:
        raise SceneError(problems + found)
    return Scene(name, path, data, raw)


def list_scenes() -> list[tuple[str, str]]:
    """(name, description) of every scene in SCENES_DIR, sorted by name."""
    scenes = []
    for path in sorted(SCENES_DIR.glob("*.toml")):
        try:
            description = tomllib.loads(path.read_text(encoding="utf-8")).get("description", "")
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
            description = f"(unreadable: {e})"
        scenes.append((path.stem, str(description)))
    return scenes


def resolve_scene_path(name_or_path: str | Path) -> Path:
    """A scene name ("dam_break_2d" -> scenes/dam_break_2d.toml) or an existing file."""
    text = str(name_or_path)
    for path in (Path(text), SCENES_DIR / text, SCENES_DIR / f"{text}.toml"):
        if path.is_file():
            return path
    names = [name for name, _ in list_scenes()]
    close = difflib.get_close_matches(Path(text).stem, names, 1)
    hint = f", did you mean '{close[0]}'?" if close else ""
    available = ", ".join(names) or f"none in {SCENES_DIR}"
    raise SceneError(
        f"{text}: no such scene or file{hint} (expected a scene name or a path "
        f"to a .toml file; available scenes: {available})"
    )


def load_scene(source: str | Path | dict, overrides: dict | list[str] | None = None) -> Scene:
    """Load, override and validate a scene; raise SceneError listing every problem.

    ``source``: a scene name, a path, or a dict shaped like the TOML file. ``overrides``:
    {"fluid.viscosity": "0.2"} (strings parsed as TOML values) or ["fluid.viscosity=0.2"]
    (as the command line's --set passes them). Problems name a dict's keys "override
    KEY", a list's "--set KEY".
    """
    if isinstance(source, dict):
        return _build(source, "<dict>", "custom", overrides)
    path = resolve_scene_path(source)
    label = _label(str(path))
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as e:
        raise SceneError(f"{label}: cannot read the file ({e})") from None
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{label}: invalid TOML: {e}") from None
    return _build(raw, str(path), path.stem, overrides)
