"""Scene schema, validation messages, overrides and loading (mrsph.scene.config; no Taichi).

``test_docs_tables_match_schema`` keeps the key tables of docs/scenes.md in step with the
schema; ``python3 tools/scene_docs.py`` regenerates them.
"""

from __future__ import annotations

import copy
import json
import math
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from toolload import load_tool

from mrsph.scene import config
from mrsph.scene.config import SCHEMA, SceneError, Table, list_scenes, load_scene, resolve_scene_path

REPO = Path(__file__).resolve().parent.parent
DIMS = [2, 3]


def minimal(dim: int) -> dict:
    """The smallest valid scene: a 1 x 1 (x 1) m box with a 0.5 m block of water."""
    return {
        "description": f"minimal {dim}D scene",
        "dim": dim,
        "domain": {"min": [0.0] * dim, "max": [1.0] * dim},
        "particles": {"spacing": 0.05},
        "fluid": {"blocks": [{"min": [0.0] * dim, "max": [0.5] * dim}]},
    }


def put(scene: dict, dotted: str, value) -> dict:
    """Set a dotted key ("fluid.blocks.0.max") in a scene dict, creating tables."""
    node = scene
    parts = dotted.split(".")
    for part in parts[:-1]:
        node = node[int(part)] if isinstance(node, list) else node.setdefault(part, {})
    if isinstance(node, list):
        node[int(parts[-1])] = value
    else:
        node[parts[-1]] = value
    return scene


def problems(scene: dict, overrides=None) -> list[str]:
    with pytest.raises(SceneError) as info:
        load_scene(scene, overrides)
    err = info.value
    assert str(err) == "\n".join(err.problems)
    return err.problems


def only_problem(scene: dict, overrides=None) -> str:
    found = problems(scene, overrides)
    assert len(found) == 1, found
    return found[0]


@pytest.fixture(params=DIMS, ids=["2d", "3d"])
def dim(request) -> int:
    return request.param


# ------------------------------------------------------------------ valid scenes, defaults
def test_minimal_scene_fills_defaults(dim):
    scene = load_scene(minimal(dim))
    assert scene.name == "custom" and scene.path == "<dict>"
    assert scene.dim == dim
    assert scene.fluid.viscosity == 1.0 and scene.fluid.eos == "linear"
    assert scene.get("fluid.rest_density") == 1000.0
    assert scene.physics.gravity == ((0.0, -9.81) if dim == 2 else (0.0, -9.81, 0.0))
    assert scene.fluid.blocks[0].velocity == (0.0,) * dim
    assert scene.fluid.blocks[0].min == (0.0,) * dim
    assert all(type(x) is float for x in scene.domain.max)
    assert scene.obstacles == () and scene.data["emitters"] == []
    assert scene.render.camera_position is None
    assert scene.run.frames == 0 and scene.run.fps == 30.0


def test_every_schema_key_is_in_data(dim):
    data = load_scene(minimal(dim)).data

    def walk(table: Table, node: dict):
        for name, sub in table.keys.items():
            assert name in node
            if isinstance(sub, Table):
                walk(sub, node[name])

    walk(SCHEMA, data)


def test_ints_accepted_where_floats_expected():
    scene = load_scene(put(minimal(2), "fluid.viscosity", 0))
    assert scene.fluid.viscosity == 0.0 and type(scene.fluid.viscosity) is float
    assert scene.domain.max == (1.0, 1.0)


def test_automatic_values_resolved(dim):
    scene = load_scene(put(minimal(dim), "adaptivity", {"enabled": True, "levels": 3}))
    n = scene.estimate_particles()
    assert n == 10**dim
    assert scene.particles.capacity == int(1.5 * n) + 1024
    assert scene.adaptivity.background_level == 2
    assert scene.adaptivity.merge_min_children == 2 ** (dim - 1)
    assert scene.adaptivity.band == pytest.approx(2 * 2.0 * 0.05 * 4)


def test_automatic_values_with_adaptivity_off():
    scene = put(put(minimal(2), "adaptivity.levels", 3), "adaptivity.enabled", False)
    adaptivity = load_scene(scene).adaptivity
    assert adaptivity.background_level == 0 and adaptivity.band == pytest.approx(2 * 2.0 * 0.05)


def test_refinement_asked_for_without_adaptivity_enabled():
    """enabled defaults to false: criteria or several levels without it would silently
    run uniform. Saying enabled = false (as --set does for a uniform twin) is fine."""
    criteria = [{"type": "obstacles", "distance": 0.1}]
    expected = (
        "<dict>: adaptivity.enabled: not set (got {} given; expected adaptivity.enabled "
        "= true to refine, or false to run uniform at the finest spacing)"
    )
    scene = minimal(2) | {"criteria": criteria}
    assert only_problem(scene) == expected.format("[[criteria]]")
    scene = minimal(2) | {"criteria": criteria, "adaptivity": {"levels": 3}}
    assert only_problem(scene) == expected.format("[[criteria]] and adaptivity.levels = 3")
    assert not load_scene(scene, {"adaptivity.enabled": "false"}).adaptivity.enabled


def test_too_many_levels_for_the_domain(dim):
    """Level n's support radius is 2^n h0 (h0 = 2 x 0.05 m here); past the domain's
    smallest side (1 m) a level has no fluid to resolve."""
    scene = put(put(minimal(dim), "adaptivity.enabled", True), "adaptivity.levels", 4)
    load_scene(scene)  # 0.8 m: fits
    put(scene, "adaptivity.levels", 5)
    assert only_problem(scene) == (
        "<dict>: adaptivity.levels: too many for the domain (got 5; expected at most 4: level 4's "
        "support radius, 1.6 m, exceeds the domain's smallest side, 1.0 m)"
    )


def test_automatic_capacity_counts_emitters(dim):
    scene = minimal(dim)
    down = [0.0, -2.0] + [0.0] * (dim - 2)
    scene["emitters"] = [
        {"center": [0.8] * dim, "radius": 0.1, "velocity": down, "start": 1.0, "stop": 3.0, "level": 1}
    ]
    scene["adaptivity"] = {"levels": 2, "enabled": True}

    def expected(s_l):
        emitted = math.ceil((2 * 0.1 / s_l) ** (dim - 1) * 2.0 / s_l * 2.0)
        return int(1.5 * 10**dim + emitted) + 1024

    assert load_scene(scene).particles.capacity == expected(0.1)
    # adaptivity off: the run has level 0 only, and the emitter adds fluid at s0
    # (the capacity was sized for level 1's spacing, 2^d times too few particles)
    scene["adaptivity"]["enabled"] = False
    assert load_scene(scene).particles.capacity == expected(0.05)


def test_emitter_counted_for_at_most_a_minute():
    scene = minimal(2)
    scene["emitters"] = [{"center": [0.8, 0.8], "radius": 0.05, "velocity": [0.0, -1.0]}]
    assert load_scene(scene).particles.capacity == int(1.5 * 100 + 2 * 20 * 60) + 1024


def test_estimate_particles_counts_lattice_points():
    scene = minimal(2)
    scene["particles"]["spacing"] = 0.1
    scene["fluid"]["blocks"] = [{"min": [0, 0], "max": [0.3, 0.25]}, {"min": [0.5, 0.5], "max": [0.7, 0.7]}]
    assert load_scene(scene).estimate_particles() == 3 * 2 + 2 * 2


def test_numpy_values_accepted(dim):
    np = pytest.importorskip("numpy")
    scene = minimal(dim)
    scene["domain"]["max"] = np.ones(dim)
    scene["particles"]["spacing"] = np.float32(0.05)
    scene["run"] = {"frames": np.int64(3)}
    s = load_scene(scene)
    assert s.domain.max == (1.0,) * dim and s.run.frames == 3 and type(s.run.frames) is int


def test_explicit_capacity_kept():
    assert load_scene(put(minimal(2), "particles.capacity", 5000)).particles.capacity == 5000


def test_full_scene_with_every_section(dim):
    z = [0.5] if dim == 3 else []
    scene = minimal(dim)
    scene["obstacles"] = [
        {"shape": "box", "min": [0.6] * dim, "max": [0.8] * dim},
        {"shape": "sphere", "center": [0.8] * dim, "radius": 0.05},
    ]
    scene["emitters"] = [{"center": [0.2] + [0.9] * (dim - 1), "radius": 0.05, "velocity": [1.0] + [0.0] * (dim - 1)}]
    scene["adaptivity"] = {"enabled": True, "levels": 3, "background_level": 2}
    scene["criteria"] = [
        {
            "type": "region",
            "shape": "sphere",
            "center": [0.5] * dim,
            "radius": 0.2,
            "level": 0,
            "path": [[0.0, 0.5, 0.5] + z, [1.0, 0.6, 0.5] + z],
            "loop": True,
        },
        {"type": "region", "shape": "box", "min": [0.0] * dim, "max": [0.3] * dim, "level": 1},
        {"type": "obstacles", "distance": 0.1},
        {"type": "disturbance"},
    ]
    scene["stirrers"] = [
        {"radius": 0.1, "strength": 5.0, "mode": "pull", "path": [[0, 0.5, 0.5] + z, [2, 0.2, 0.5] + z]}
    ]
    scene["render"] = {"background": [0, 0, 0]}
    if dim == 3:
        scene["render"]["camera_position"] = [2, 2, 2]
    s = load_scene(scene)
    assert s.criteria[0].path[1] == (1.0, 0.6, 0.5) + tuple(z)
    assert s.criteria[2].distance == 0.1 and s.criteria[3].level == 0
    assert s.stirrers[0].loop is True and s.stirrers[0].mode == "pull"
    assert s.emitters[0].stop == 1e9 and s.emitters[0].level == 0
    assert s.obstacles[1].shape == "sphere" and s.obstacles[1].radius == 0.05


def test_no_blocks_allowed_with_an_emitter():
    scene = minimal(2)
    scene["fluid"]["blocks"] = []
    scene["emitters"] = [{"center": [0.5, 0.9], "radius": 0.05, "velocity": [0.0, -1.0]}]
    assert load_scene(scene).estimate_particles() == 0


# ------------------------------------------------------------------------ per-key rules
def test_out_of_range_line_format():
    assert only_problem(put(minimal(2), "fluid.viscosity", -1.0)) == (
        "<dict>: fluid.viscosity: out of range (got -1.0; expected a number >= 0)"
    )


def test_wrong_type_names_the_type():
    assert only_problem(put(minimal(2), "fluid.viscosity", "abc")) == (
        '<dict>: fluid.viscosity: wrong type (got "abc" (string); expected a number >= 0)'
    )


def test_bool_is_not_a_number():
    line = only_problem(put(minimal(2), "fluid.stiffness", True))
    assert "fluid.stiffness: wrong type (got true (boolean); expected a number > 0)" in line


def test_float_is_not_an_integer():
    line = only_problem(put(minimal(2), "adaptivity.levels", 2.0))
    assert "adaptivity.levels: wrong type (got 2.0 (float); expected an integer in [1, 6])" in line


@pytest.mark.parametrize(
    "key, value, expected",
    [
        ("dim", 4, "an integer in [2, 3]"),
        ("description", 3, "a one-line string"),
        ("description", "two\nlines", "a one-line string"),
        ("domain.restitution", 1.5, "a number in [0, 1]"),
        ("domain.friction", -0.1, "a number in [0, 1]"),
        ("particles.spacing", 0, "a number > 0"),
        ("particles.support", 1.0, "a number in [1.5, 4]"),
        ("particles.capacity", -1, "an integer >= 0"),
        ("particles.precision", "f16", 'one of "f32", "f64"'),
        ("fluid.rest_density", 0, "a number > 0"),
        ("fluid.eos", "ideal", 'one of "linear", "tait"'),
        ("fluid.stiffness", -5, "a number > 0"),
        ("fluid.gamma", 11, "a number in [1, 10]"),
        ("fluid.clamp_negative_pressure", 1, "true or false"),
        ("fluid.blocks.0.velocity", "fast", "a list of 2 numbers"),
        ("particles.capacity", 2_000_000_000, "<= 52000000 in 2D"),
        ("physics.cfl", 0, "a number in (0, 1]"),
        ("physics.cfl", 1.5, "a number in (0, 1]"),
        ("physics.force_factor", 0.0, "a number in (0, 1]"),
        ("physics.dt_max", 0, "a number > 0"),
        ("physics.dt_min", -1e-7, "a number > 0"),
        ("physics.max_speed", float("inf"), "a number > 0"),
        ("physics.gravity", [0, "down"], "a list of 2 numbers"),
        ("adaptivity.enabled", "yes", "true or false"),
        ("adaptivity.levels", 0, "an integer in [1, 6]"),
        ("adaptivity.levels", 7, "an integer in [1, 6]"),
        ("adaptivity.interval", 0, "an integer >= 1"),
        ("adaptivity.hysteresis", 0.6, "a number in [0, 0.5)"),
        ("adaptivity.band", -1, "a number >= 0"),
        ("adaptivity.spring_rate", -1, "a number >= 0"),
        ("adaptivity.release_factor", 2.5, "a number in [0.5, 2]"),
        ("adaptivity.merge_min_children", -1, "an integer >= 0"),
        ("adaptivity.gather_factor", 0, "a number in (0, 2]"),
        ("adaptivity.gather_span", 1, "a number in (0, 1)"),
        ("adaptivity.merge_remnants", 1, "true or false"),
        ("adaptivity.split_relax", "lattice", 'one of "spacing", "density"'),
        ("adaptivity.split_density_tolerance", 0.2, "a number in [0, 0.1]"),
        ("adaptivity.background_level", -2, "an integer >= -1"),
        ("run.fps", 0, "a number in [0.1, 1000]"),
        ("run.fps", 1e-3, "a number in [0.1, 1000]"),
        ("run.frames", -1, "an integer >= 0"),
        ("render.width", 10, "an integer in [64, 8192]"),
        ("render.height", 9000, "an integer in [64, 8192]"),
        ("render.background", [0.1, 0.2, 1.5], "a list of 3 numbers in [0, 1]"),
        ("render.background", [0.1, 0.2], "a list of 3 numbers in [0, 1]"),
        ("render.point_scale", 0, "a number > 0"),
    ],
)
def test_bad_value_reported(key, value, expected):
    line = only_problem(put(minimal(2), key, value))
    assert line.startswith(f"<dict>: {key}: ")
    assert f"expected {expected})" in line
    if isinstance(value, str):
        assert f"(got {json.dumps(value)}" in line


@pytest.mark.parametrize(
    "key, value",
    [
        ("physics.max_speed", float("nan")),
        ("domain.max", [float("inf"), 0.5]),
        ("fluid.blocks.0.velocity", [0.0, float("-inf")]),
    ],
)
def test_non_finite_value_named_as_such(key, value):
    line = only_problem(put(minimal(2), key, value))
    assert line.startswith(f"<dict>: {key}: not finite (got "), line


def test_unknown_choice_hints_the_nearest():
    line = only_problem(put(minimal(2), "fluid.eos", "tiat"))
    assert line == (
        '<dict>: fluid.eos: unknown choice, did you mean \'tait\'? (got "tiat"; expected one of "linear", "tait")'
    )


def test_unknown_key_did_you_mean():
    assert only_problem(put(minimal(2), "fluid.viscosty", 0.1)) == (
        "<dict>: fluid.viscosty: unknown key (did you mean 'viscosity'?)"
    )


def test_unknown_section_did_you_mean():
    assert only_problem(put(minimal(2), "fluids", {})) == ("<dict>: fluids: unknown key (did you mean 'fluid'?)")


def test_unknown_key_without_close_match_lists_keys():
    line = only_problem(put(minimal(2), "domain.zzz", 1))
    assert line == ("<dict>: domain.zzz: unknown key (expected one of 'friction', 'max', 'min', 'restitution')")


@pytest.mark.parametrize(
    "key",
    [
        "description",
        "dim",
        "domain",
        "particles",
        "fluid",
        "domain.min",
        "domain.max",
        "particles.spacing",
        "fluid.blocks.0.min",
    ],
)
def test_missing_required_key(key):
    scene = minimal(2)
    *head, last = key.split(".")
    node = scene
    for part in head:
        node = node[int(part)] if isinstance(node, list) else node[part]
    del node[last]
    found = problems(scene)
    start = f"<dict>: {key}: missing required key (expected "
    assert any(line.startswith(start) for line in found), found
    if key in ("description", "dim", "domain", "particles", "domain.min", "particles.spacing"):
        assert len(found) == 1, found  # nothing else is reported for the missing piece


def test_missing_vector_says_its_length(dim):
    scene = minimal(dim)
    del scene["domain"]["max"]
    assert only_problem(scene) == (f"<dict>: domain.max: missing required key (expected a list of {dim} numbers)")


def test_vector_of_wrong_length(dim):
    scene = put(minimal(dim), "physics.gravity", [0.0] * (5 - dim))
    assert only_problem(scene) == (
        f"<dict>: physics.gravity: wrong length (got {[0.0] * (5 - dim)}; expected a list of {dim} numbers)"
    )


def test_vector_lengths_follow_dim_everywhere(dim):
    other = 5 - dim
    scene = minimal(dim)
    scene["domain"]["min"] = [0.0] * other
    scene["fluid"]["blocks"][0]["velocity"] = [0.0] * other
    scene["obstacles"] = [{"shape": "sphere", "center": [0.9] * other, "radius": 0.05}]
    found = problems(scene)
    assert [line.split(":")[1].strip() for line in found] == [
        "domain.min",
        "fluid.blocks.0.velocity",
        "obstacles.0.center",
    ]
    assert all(f"expected a list of {dim} numbers" in line for line in found)


def test_wrong_table_type():
    assert only_problem(put(minimal(2), "physics", 3)) == (
        "<dict>: physics: wrong type (got 3 (integer); expected a table)"
    )


def test_wrong_array_type():
    assert only_problem(put(minimal(2), "obstacles", {"shape": "box"})).startswith(
        "<dict>: obstacles: wrong type (got {shape = \"box\"} (table); expected an array of tables"
    )


def test_obstacle_keys_depend_on_shape(dim):
    scene = minimal(dim)
    scene["obstacles"] = [
        {"shape": "box", "min": [0.7] * dim, "max": [0.9] * dim, "radius": 1.0},
        {"shape": "sphere", "center": [0.8] * dim},
    ]
    assert problems(scene) == [
        "<dict>: obstacles.0.radius: unknown key (expected one of 'max', 'min', 'shape')",
        "<dict>: obstacles.1.radius: missing required key (expected a number > 0)",
    ]


def test_obstacle_shape_missing_or_unknown():
    scene = minimal(2)
    scene["obstacles"] = [{"min": [0.7, 0.7], "max": [0.9, 0.9]}, {"shape": "cube"}]
    assert problems(scene) == [
        '<dict>: obstacles.0.shape: missing required key (expected one of "box", "sphere")',
        '<dict>: obstacles.1.shape: unknown choice (got "cube"; expected one of "box", "sphere")',
    ]


def test_criteria_keys_depend_on_type():
    scene = minimal(2)
    scene["criteria"] = [
        {"type": "disturbance", "distance": 0.1},
        {"type": "obstacles", "shape": "box"},
        {"type": "region", "shape": "box", "min": [0, 0]},
        {"type": "regoin"},
    ]
    assert problems(scene) == [
        "<dict>: criteria.0.distance: unknown key (expected one of 'level', 'type')",
        "<dict>: criteria.1.shape: unknown key (expected one of 'distance', 'level', 'type')",
        "<dict>: criteria.2.max: missing required key (expected a list of 2 numbers)",
        "<dict>: criteria.3.type: unknown choice, did you mean 'region'? "
        '(got "regoin"; expected one of "region", "obstacles", "disturbance")',
    ]


@pytest.mark.parametrize(
    "shape, what",
    [
        (None, 'missing required key (expected one of "box", "sphere")'),
        ("cube", 'unknown choice (got "cube"; expected one of "box", "sphere")'),
        (1, 'wrong type (got 1 (integer); expected one of "box", "sphere")'),
    ],
)
def test_region_criterion_shape_missing_or_unknown(shape, what):
    """A switch inside a switch (criterion type, then region shape): a bad inner one is
    reported like the outer one (it used to end in a TypeError traceback)."""
    scene = minimal(2)
    scene["criteria"] = [{"type": "region"} | ({} if shape is None else {"shape": shape})]
    assert problems(scene) == [f"<dict>: criteria.0.shape: {what}"]


@pytest.mark.parametrize(
    "path, what",
    [
        ([[0, 0.1, 0.1], [0, 0.2, 0.2]], "waypoint times not strictly increasing"),
        ([[1, 0.1, 0.1], [0, 0.2, 0.2]], "waypoint times not strictly increasing"),
        ([[0, 0.1, 0.1], [1, 0.2]], "waypoint of the wrong length"),
        ([[0, 0.1, 0.1]], "too few waypoints"),
        ([0, 0.1, 0.1], "wrong type"),
    ],
)
def test_stirrer_path_rules(path, what):
    scene = minimal(2)
    scene["stirrers"] = [{"radius": 0.1, "strength": 1.0, "path": path}]
    line = only_problem(scene)
    assert line.startswith(f"<dict>: stirrers.0.path: {what} (got ")
    assert line.endswith("expected a list of >= 2 waypoints [t, x, y] with strictly increasing t)")


def test_stirrer_waypoint_outside_the_domain():
    """A stirrer outside the domain stirs nothing; the path is checked waypoint by waypoint."""
    scene = minimal(2)
    scene["stirrers"] = [
        {"radius": 0.1, "strength": 1.0, "path": [[0, 0.5, 0.5], [1, 0.9, 0.5]]},
        {"radius": 0.1, "strength": 1.0, "path": [[0, 0.5, 0.5], [1, 5.0, 6.0]]},
    ]
    assert only_problem(scene) == (
        "<dict>: stirrers.1.path: waypoint outside the domain (got [1.0, 5.0, 6.0]; expected "
        "every waypoint's position inside the domain [0.0, 0.0] .. [1.0, 1.0])"
    )


def test_criterion_path_in_3d_needs_four_numbers():
    scene = minimal(3)
    scene["criteria"] = [
        {"type": "region", "shape": "sphere", "center": [0.5] * 3, "radius": 0.1, "path": [[0, 0.5, 0.5]]}
    ]
    assert only_problem(scene) == (
        "<dict>: criteria.0.path: waypoint of the wrong length (got [[0, 0.5, 0.5]]; "
        "expected a list of >= 1 waypoints [t, x, y, z] with strictly increasing t)"
    )


def test_stirrer_required_keys():
    scene = minimal(2)
    scene["stirrers"] = [{"radius": 0.1}]
    assert problems(scene) == [
        "<dict>: stirrers.0.strength: missing required key (expected a number >= 0)",
        "<dict>: stirrers.0.path: missing required key "
        "(expected a list of >= 2 waypoints [t, x, y] with strictly increasing t)",
    ]


# --------------------------------------------------------------------- cross-field rules
@pytest.mark.parametrize("key", ["domain", "fluid.blocks.0", "obstacles.0"])
def test_max_must_exceed_min(key):
    scene = minimal(2)
    scene["obstacles"] = [{"shape": "box", "min": [0.7, 0.7], "max": [0.9, 0.9]}]
    put(scene, f"{key}.max", [0.95, 0.0])
    line = only_problem(scene)
    lo = {"domain": "[0.0, 0.0]", "fluid.blocks.0": "[0.0, 0.0]", "obstacles.0": "[0.7, 0.7]"}[key]
    assert line == (f"<dict>: {key}.max: not above min (got [0.95, 0.0]; expected every component > min = {lo})")


def test_fluid_block_outside_domain(dim):
    scene = put(minimal(dim), "fluid.blocks.0.max", [1.5] + [0.5] * (dim - 1))
    line = only_problem(scene)
    ones, zeros = [1.0] * dim, [0.0] * dim
    assert line == (
        f"<dict>: fluid.blocks.0: outside the domain (got min {zeros}, max "
        f"{[1.5] + [0.5] * (dim - 1)}; expected inside the domain {zeros} .. {ones})"
    )


def test_fluid_block_overlapping_box_obstacle(dim):
    scene = minimal(dim)
    scene["obstacles"] = [
        {"shape": "box", "min": [0.5] * dim, "max": [0.6] * dim},  # touches only
        {"shape": "box", "min": [0.4] * dim, "max": [0.6] * dim},
    ]
    line = only_problem(scene)
    assert line.startswith("<dict>: fluid.blocks.0: overlaps obstacles.1 (got min ")
    assert line.endswith(f"expected no overlap with the box {[0.4] * dim} .. {[0.6] * dim})")


def test_fluid_block_overlapping_sphere_obstacle(dim):
    scene = minimal(dim)
    scene["obstacles"] = [
        {"shape": "sphere", "center": [0.6] * dim, "radius": 0.1},  # corner gap
        {"shape": "sphere", "center": [0.55] + [0.25] * (dim - 1), "radius": 0.1},
    ]
    line = only_problem(scene)
    assert line.startswith("<dict>: fluid.blocks.0: overlaps obstacles.1 (got min ")
    assert "expected no overlap with the sphere at" in line and "radius 0.1)" in line


def test_no_fluid_at_all():
    assert only_problem(put(minimal(2), "fluid.blocks", [])) == (
        "<dict>: fluid.blocks: no fluid (got no [[fluid.blocks]] and no [[emitters]]; "
        "expected at least one [[fluid.blocks]] or one [[emitters]])"
    )


def test_fluid_blocks_of_the_wrong_type_are_not_also_no_fluid():
    """The wrong type is the problem; an array read as empty is not a second one."""
    for key in ("fluid.blocks", "emitters"):
        assert problems(put(minimal(2), key, 3)) == [
            f"<dict>: {key}: wrong type (got 3 (integer); expected an array of tables [[{key}]])"
        ]


def test_a_looping_region_needs_a_path_to_repeat(dim):
    region = {"type": "region", "level": 0, "shape": "sphere", "center": [0.5] * dim, "radius": 0.1, "loop": True}
    scene = put(put(minimal(dim), "adaptivity", {"enabled": True, "levels": 2}), "criteria", [region])
    expected = "expected a path of at least 2 waypoints with loop = true)"
    assert only_problem(scene) == f"<dict>: criteria.0.loop: nothing to repeat (got no path; {expected}"
    region["path"] = [[0.0] + [0.5] * dim]
    assert only_problem(scene) == (
        f"<dict>: criteria.0.loop: nothing to repeat (got a path of one waypoint; {expected}"
    )
    region["path"] = [[0.0] + [0.5] * dim, [1.0] + [0.6] * dim]
    assert load_scene(scene).criteria[0].loop
    region["path"] = [[0.0, 0.5]]  # a bad path is reported once, as itself
    assert only_problem(scene).startswith("<dict>: criteria.0.path: waypoint of the wrong length")


def test_emitter_rules(dim):
    scene = minimal(dim)
    scene["emitters"] = [{"center": [1.5] * dim, "radius": 0.05, "velocity": [0.0] * dim, "start": 2.0, "stop": 1.0}]
    assert problems(scene) == [
        f"<dict>: emitters.0.center: outside the domain (got {[1.5] * dim}; "
        f"expected inside the domain {[0.0] * dim} .. {[1.0] * dim})",
        f"<dict>: emitters.0.velocity: zero velocity (got {[0.0] * dim}; "
        "expected a non-zero vector; the emitting disc faces along it)",
        "<dict>: emitters.0.stop: not after start (got 1.0; expected a number > start = 2.0)",
    ]


def test_a_settle_is_refused_with_emitters_or_stirrers(dim):
    """The settle runs before t = 0, where an emitter's start and a stirrer's path have no time."""
    scene = put(minimal(dim), "fluid.settle", 0.2)
    assert load_scene(scene).fluid.settle == 0.2
    scene["emitters"] = [{"center": [0.9] * dim, "radius": 0.05, "velocity": [-1.0] + [0.0] * (dim - 1)}]
    expected = "expected 0 in a scene with [[emitters]]"
    assert only_problem(scene) == f"<dict>: fluid.settle: with emitters (got 0.2; {expected})"
    del scene["emitters"]
    scene["stirrers"] = [{"radius": 0.1, "strength": 1.0, "path": [[0.0] + [0.5] * dim, [1.0] + [0.6] * dim]}]
    expected = "expected 0 in a scene with [[stirrers]]"
    assert only_problem(scene) == f"<dict>: fluid.settle: with stirrers (got 0.2; {expected})"


def test_fluid_blocks_overlapping_each_other(dim):
    """Each block gets its own lattice: overlapping blocks would start at twice the
    density there and burst apart. Blocks that only touch are fine."""
    scene = minimal(dim)
    scene["fluid"]["blocks"] += [
        {"min": [0.5] + [0.0] * (dim - 1), "max": [0.8] + [0.5] * (dim - 1)},
        {"min": [0.1] * dim, "max": [0.3] * dim},
    ]
    line = only_problem(scene)
    assert line.startswith("<dict>: fluid.blocks.2: overlaps fluid.blocks.0 (got min "), line
    assert line.endswith(
        f"expected blocks that at most touch (no overlap with the box {[0.0] * dim} .. {[0.5] * dim}))"
    ), line


def test_emitter_outlet_inside_an_obstacle_or_outside_the_domain(dim):
    """Every point an emitter places must lie in the fluid's space: one placed inside a
    solid is thrown out of it at many times the emitter's speed."""
    scene = minimal(dim)
    scene["obstacles"] = [{"shape": "sphere", "center": [0.8] * dim, "radius": 0.1}]
    down = [0.0, -1.0] + [0.0] * (dim - 2)
    scene["emitters"] = [
        {"center": [0.8] * dim, "radius": 0.02, "velocity": down},  # in the sphere
        {"center": [0.98] * dim, "radius": 0.05, "velocity": down},  # past the wall
        {
            "center": [0.7, 0.9] + [0.7] * (dim - 2),
            "radius": 0.05,  # clear
            "velocity": down,
        },
    ]
    found = problems(scene)
    assert len(found) == 2, found
    assert found[0] == (
        f"<dict>: emitters.0: outlet inside obstacles.0 (got centre {[0.8] * dim}, "
        "radius 0.02; expected a disc clear of the sphere obstacles.0)"
    )
    assert found[1].startswith(
        f"<dict>: emitters.1: outlet outside the domain (got centre {[0.98] * dim}, radius 0.05; "
        f"expected a disc inside the domain {[0.0] * dim} .. {[1.0] * dim} (its point "
    ), found[1]
    assert "1.03" in found[1].rsplit("its point", 1)[1], found[1]  # 0.98 + 0.05 along the disc


def test_region_centre_outside_domain(dim):
    scene = minimal(dim)
    scene["adaptivity"] = {"enabled": True, "levels": 2}
    scene["criteria"] = [
        {"type": "region", "shape": "box", "min": [0.8] * dim, "max": [2.0] * dim},
        {"type": "region", "shape": "sphere", "center": [-0.5] * dim, "radius": 1.0},
    ]
    found = problems(scene)
    assert [line.split(" (")[0] for line in found] == [
        "<dict>: criteria.0: region centre outside the domain",
        "<dict>: criteria.1: region centre outside the domain",
    ]
    assert f"got {[1.4] * dim}" in found[0]


def test_adaptivity_needs_two_levels():
    scene = put(minimal(2), "adaptivity", {"enabled": True})
    assert only_problem(scene) == (
        "<dict>: adaptivity.levels: too few levels for adaptivity "
        "(got 1; expected an integer >= 2 when adaptivity.enabled = true)"
    )


def test_levels_must_exist():
    scene = minimal(2)
    scene["adaptivity"] = {"enabled": True, "levels": 2, "background_level": 2}
    scene["criteria"] = [{"type": "disturbance", "level": 2}]
    scene["emitters"] = [{"center": [0.5, 0.9], "radius": 0.05, "velocity": [0, -1], "level": 5}]
    expected = "expected an integer < adaptivity.levels = 2)"
    assert problems(scene) == [
        f"<dict>: emitters.0.level: no such level (got 5; {expected}",
        f"<dict>: criteria.0.level: no such level (got 2; {expected}",
        f"<dict>: adaptivity.background_level: no such level (got 2; {expected}",
    ]


def test_merge_group_not_larger_than_a_parent(dim):
    line = only_problem(put(minimal(dim), "adaptivity.merge_min_children", 2**dim + 1))
    assert line == (
        f"<dict>: adaptivity.merge_min_children: more children than a parent has "
        f"(got {2**dim + 1}; expected an integer <= 2^dim = {2**dim}, or 0)"
    )


def test_capacity_too_small(dim):
    line = only_problem(put(minimal(dim), "particles.capacity", 50))
    assert line == (
        f"<dict>: particles.capacity: too small for the fluid blocks (got 50; "
        f"expected >= {10**dim}, the lattice points of fluid.blocks; "
        "raise particles.capacity or use 0 for automatic)"
    )


def test_automatic_capacity_too_large(dim):
    """Too many particles for any machine: refused before Taichi tries to allocate them
    (2e9 slots ended in a host_memory_pool traceback)."""
    scene = put(minimal(dim), "domain.max", [40.0] * dim)
    scene["fluid"]["blocks"][0]["max"] = [40.0] * dim
    scene["particles"]["spacing"] = 0.08 if dim == 3 else 0.003
    scene["particles"]["skin"] = 0.0  # the limit without a skin (tests/test_skin.py has it with one)
    line = only_problem(scene)
    assert line.startswith("<dict>: particles.spacing: too many particles for the pool (got "), line
    limit = {2: 52_000_000, 3: 26_000_000}[dim]
    assert line.endswith(f"expected <= {limit} in {dim}D; raise particles.spacing or shrink the fluid)"), line


def test_capacity_past_what_the_neighbour_lists_index(dim):
    """slots x (MAX_NEIGHBOURS + 1) must stay below 2^31, Taichi's field index: 52 M
    slots in 2D, 26 M in 3D. 9e7 slots in 2D passed the old limit (1e8), then Taichi
    stopped on an int32 overflow of the neighbour lists."""
    limit = {2: 52_000_000, 3: 26_000_000}[dim]
    no_skin = put(minimal(dim), "particles.skin", 0.0)  # tests/test_skin.py has the limit with one
    assert only_problem(put(no_skin, "particles.capacity", limit + 1)) == (
        f"<dict>: particles.capacity: too many slots for the neighbour lists "
        f"(got {limit + 1}; expected <= {limit} in {dim}D)"
    )
    assert load_scene(put(no_skin, "particles.capacity", limit)).particles.capacity == limit


def test_domain_too_large_for_grid(dim):
    scene = put(minimal(dim), "domain.max", [1000.0] * dim)
    scene["fluid"]["blocks"][0]["max"] = [0.1] * dim  # few particles: only the grid is too large
    scene["particles"]["spacing"] = 0.001
    line = only_problem(scene)
    assert line.startswith("<dict>: domain: too large for the neighbour grid (got ")
    assert "cells of size h0 = 0.002 m; expected <= 5e+07 cells" in line


def test_more_entries_than_the_fields_hold():
    """Criteria, stirrers and obstacles of one shape live in fixed-size Taichi fields: a
    scene with more is refused with the limit (it used to stop with a traceback, or run
    with the stirrers past the 7th silently left out)."""
    scene = minimal(2)
    scene["criteria"] = [{"type": "disturbance"}] * 17
    scene["stirrers"] = [{"radius": 0.1, "strength": 1.0, "path": [[0, 0.2, 0.8], [1, 0.8, 0.8]]}] * 8
    scene["obstacles"] = [{"shape": "sphere", "center": [0.8, 0.8], "radius": 0.01}] * 33 + [
        {"shape": "box", "min": [0.7, 0.7], "max": [0.72, 0.72]}
    ] * 32
    assert problems(scene) == [
        "<dict>: criteria: too many entries (got 17; expected at most 16)",
        "<dict>: stirrers: too many entries (got 8; expected at most 7)",
        "<dict>: obstacles: too many of shape sphere (got 33; expected at most 32)",
    ]


def test_as_many_entries_as_the_fields_hold_run():
    """The limits above are the fields' sizes, not one less: 16 criteria, 7 stirrers and 32
    spheres and 32 boxes load, and every stirrer acts (its disturbance slot is active)."""
    from mrsph.simulation import Simulation

    scene = minimal(2)
    scene["adaptivity"] = {"enabled": True, "levels": 2}
    scene["criteria"] = [{"type": "disturbance"}] * 16
    scene["stirrers"] = [{"radius": 0.1, "strength": 1.0, "path": [[0, 0.2, 0.8], [1, 0.8, 0.8]]}] * 7
    scene["obstacles"] = [{"shape": "sphere", "center": [0.8, 0.8], "radius": 0.01}] * 32 + [
        {"shape": "box", "min": [0.7, 0.7], "max": [0.72, 0.72]}
    ] * 32
    sim = Simulation(load_scene(scene), arch="cpu")
    active = sim.disturbances.active.to_numpy()
    assert active[1:].sum() == 7, f"active disturbance slots {active}; expected the 7 stirrers'"


def test_dt_min_below_dt_max():
    scene = put(minimal(2), "physics", {"dt_min": 0.01, "dt_max": 0.001})
    assert only_problem(scene) == (
        "<dict>: physics.dt_min: not below dt_max (got 0.01; expected a number < dt_max = 0.001)"
    )


def test_camera_only_in_3d():
    line = only_problem(put(minimal(2), "render.camera_position", [1, 1, 1]))
    assert line == (
        "<dict>: render.camera_position: only for 3D scenes (got [1.0, 1.0, 1.0]; expected no camera keys when dim = 2)"
    )


def test_all_problems_reported_at_once():
    scene = minimal(2)
    scene["fluid"]["viscosty"] = 0.1  # unknown key
    scene["fluid"]["stiffness"] = "stiff"  # wrong type
    scene["domain"]["restitution"] = 2.0  # out of range
    scene["physics"] = {"gravity": [0, -9.81, 0]}  # wrong length
    scene["fluid"]["blocks"].append({"min": [0.5, 0.5], "max": [2.0, 0.9]})  # outside
    scene["particles"]["capacity"] = 10  # too small
    scene["adaptivity"] = {"enabled": True}  # one level only
    found = problems(scene)
    assert len(found) == 7, found
    keys = [line.split(": ")[1] for line in found]
    assert keys == [
        "domain.restitution",
        "fluid.stiffness",
        "fluid.viscosty",
        "physics.gravity",
        "fluid.blocks.1",
        "adaptivity.levels",
        "particles.capacity",
    ]


def test_problem_in_one_entry_does_not_hide_the_others():
    scene = minimal(2)
    scene["fluid"]["blocks"].append({"min": [0.6, 0.6], "max": "x"})
    scene["obstacles"] = [{"shape": "sphere", "center": [0.1, 0.1], "radius": 0.05}]
    found = problems(scene)
    assert len(found) == 2
    assert found[0].startswith("<dict>: fluid.blocks.1.max: wrong type")
    assert found[1].startswith("<dict>: fluid.blocks.0: overlaps obstacles.0")


# ----------------------------------------------------------------------------- overrides
def test_overrides_parse_toml_values():
    scene = load_scene(
        minimal(2),
        {
            "fluid.viscosity": "0.2",
            "fluid.clamp_negative_pressure": "false",
            "physics.gravity": "[0, -1]",
            "fluid.eos": '"tait"',
            "particles.precision": "f64",
            "run.frames": 12,
        },
    )
    assert scene.fluid.viscosity == 0.2 and scene.fluid.clamp_negative_pressure is False
    assert scene.physics.gravity == (0.0, -1.0) and scene.fluid.eos == "tait"
    assert scene.particles.precision == "f64" and scene.run.frames == 12


def test_overrides_as_cli_list(dim):
    scene = load_scene(
        minimal(dim),
        [
            "fluid.viscosity=0.3",
            f"fluid.blocks.0.max={[0.2] * dim}",
            "adaptivity.enabled = true",
            "adaptivity.levels=2",
        ],
    )
    assert scene.fluid.viscosity == 0.3 and scene.fluid.blocks[0].max == (0.2,) * dim
    assert scene.adaptivity.enabled and scene.adaptivity.levels == 2


def test_override_can_add_an_entry():
    scene = load_scene(
        minimal(2), ["obstacles.0.shape=sphere", "obstacles.0.center=[0.8, 0.8]", "obstacles.0.radius=0.1"]
    )
    assert scene.obstacles[0].radius == 0.1


def test_override_replaces_a_whole_array():
    scene = load_scene(minimal(2), {"fluid.blocks": "[{min = [0, 0], max = [0.2, 0.2]}]"})
    assert scene.fluid.blocks[0].max == (0.2, 0.2) and scene.estimate_particles() == 16


def test_unknown_override_key():
    assert only_problem(minimal(2), ["fluid.viscosty=0.2"]) == (
        "--set fluid.viscosty: unknown key (did you mean 'viscosity'?)"
    )


def test_bad_override_value_is_labelled_with_set():
    assert only_problem(minimal(2), ["fluid.viscosity=-1"]) == (
        "--set fluid.viscosity: out of range (got -1; expected a number >= 0)"
    )
    assert only_problem(minimal(2), ["fluid.eos=ideal"]).startswith('--set fluid.eos: unknown choice (got "ideal"; ')


def test_bad_key_inside_a_whole_table_override_is_named_in_full():
    assert only_problem(minimal(2), ["physics={cfl = 5.0}"]) == (
        "--set physics: physics.cfl: out of range (got 5.0; expected a number in (0, 1])"
    )
    assert only_problem(minimal(2), ["fluid.blocks=[{min = [0, 0], max = [0.2]}]"]).startswith(
        "--set fluid.blocks: fluid.blocks.0.max: "
    )


def test_overrides_from_python_are_not_called_set():
    """A dict of overrides comes from Python, where there is no --set to name: its problems
    say "override" (a list of KEY=VALUE strings is what the command line passes)."""
    assert only_problem(minimal(2), {"fluid.viscosity": -1}) == (
        "override fluid.viscosity: out of range (got -1; expected a number >= 0)"
    )
    assert only_problem(minimal(2), {"fluid.viscosty": 1}) == (
        "override fluid.viscosty: unknown key (did you mean 'viscosity'?)"
    )
    assert only_problem(minimal(2), {"physics": {"cfl": 5.0}}) == (
        "override physics: physics.cfl: out of range (got 5.0; expected a number in (0, 1])"
    )
    found = problems(minimal(2), {"particles.spacing": 5.0})
    assert found and all(f.startswith("<dict> with override particles.spacing: ") for f in found), found


def test_malformed_overrides():
    found = problems(minimal(2), ["viscosity", "fluid.blocks.5.min=[0, 0]", "fluid.viscosity.x=1"])
    assert found == [
        '--set viscosity: not KEY=VALUE (got "viscosity"; expected for example fluid.viscosity=0.2)',
        "--set fluid.blocks.5.min: no such entry (got 5; expected an index from 0 to 1, where 1 adds an entry)",
        "--set fluid.viscosity.x: unknown key (fluid.viscosity is a value, not a table)",
    ]


def test_override_problems_and_scene_problems_together():
    found = problems(put(minimal(2), "fluid.gamma", 0), ["run.fsp=10"])
    assert found == [
        "--set run.fsp: unknown key (did you mean 'fps'?)",
        "<dict>: fluid.gamma: out of range (got 0; expected a number in [1, 10])",
    ]


def test_mass_is_exact_only_where_full_groups_merge():
    from mrsph.scene.config import mass_exact

    assert mass_exact(load_scene("dam_break_2d").data)  # uniform
    assert not mass_exact(load_scene("demo_2d").data)  # remnants merge
    assert not mass_exact(load_scene("region_2d").data)  # groups of 2 merge
    assert mass_exact(load_scene("region_2d", ["adaptivity.merge_min_children=4"]).data)
    assert not mass_exact(load_scene("region_3d", ["adaptivity.merge_min_children=4"]).data)


def test_a_scene_problem_is_not_blamed_on_an_unrelated_set():
    """The scene's own problems keep the scene's label; only those the --set values may
    have caused say "with --set"."""
    scene = put(minimal(2), "fluid.gamma", 0)
    assert problems(scene, ["physics.cfl=0.3"]) == [
        "<dict>: fluid.gamma: out of range (got 0; expected a number in [1, 10])"
    ]
    found = problems(scene, ["domain.max=[0.1, 0.1]"])
    assert found[0] == "<dict>: fluid.gamma: out of range (got 0; expected a number in [1, 10])"
    assert found[1].startswith("<dict> with --set domain.max: fluid.blocks.0: outside the domain")


def test_with_overrides_revalidates_a_copy():
    scene = load_scene(minimal(2))
    finer = scene.with_overrides({"particles.spacing": "0.01"})
    assert finer.particles.capacity == int(1.5 * 50 * 50) + 1024  # automatic, recomputed
    assert scene.particles.spacing == 0.05 and finer.name == scene.name
    with pytest.raises(SceneError, match="fluid.viscosity: out of range"):
        scene.with_overrides(["fluid.viscosity=-2"])


def test_overrides_do_not_touch_the_callers_dict():
    scene = minimal(2)
    before = copy.deepcopy(scene)
    load_scene(
        scene,
        ["fluid.viscosity=0.3", "obstacles.0.shape=box", "obstacles.0.min=[0.8,0.8]", "obstacles.0.max=[0.9,0.9]"],
    )
    assert scene == before


# ------------------------------------------------------------------------ scene access
def test_attribute_access_and_get(dim):
    scene = load_scene(minimal(dim))
    assert scene.get("fluid.blocks.0.max") == (0.5,) * dim
    assert scene["fluid"]["viscosity"] == scene.fluid.viscosity
    assert "viscosity" in scene.fluid
    with pytest.raises(AttributeError, match="did you mean 'viscosity'"):
        _ = scene.fluid.viscosty
    with pytest.raises(KeyError, match="fluid.viscosty: no such key"):
        scene.get("fluid.viscosty")
    with pytest.raises(KeyError, match="fluid.blocks.3"):
        scene.get("fluid.blocks.3")


def test_scene_error_carries_problem_lines():
    err = SceneError(["a: b: c", "d: e: f"])
    assert err.problems == ["a: b: c", "d: e: f"] and str(err) == "a: b: c\nd: e: f"
    assert SceneError("one").problems == ["one"]


# ---------------------------------------------------------------------- files and names
SCENE_TOML = """\
description = "a small dam break"
dim = 2
[domain]
min = [0, 0]
max = [1, 1]
[particles]
spacing = 0.05
[fluid]
viscosity = 0.1
[[fluid.blocks]]
min = [0, 0]
max = [0.5, 0.5]
"""


def problems_of(source) -> list[str]:
    with pytest.raises(SceneError) as info:
        load_scene(source)
    return info.value.problems


@pytest.fixture
def scenes_dir(tmp_path, monkeypatch) -> Path:
    """A scenes/ folder in a temporary working directory, used by the name look-ups."""
    folder = tmp_path / "scenes"
    folder.mkdir()
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(config.loading, "SCENES_DIR", folder)
    return folder


def test_load_toml_file_by_name_and_path(scenes_dir):
    (scenes_dir / "dam.toml").write_text(SCENE_TOML)
    by_name = load_scene("dam")
    assert by_name.name == "dam" and by_name.fluid.viscosity == 0.1
    assert Path(by_name.path) == scenes_dir / "dam.toml"
    by_path = load_scene(scenes_dir / "dam.toml", ["fluid.viscosity=0.2"])
    assert by_path.fluid.viscosity == 0.2
    assert load_scene("scenes/dam.toml").name == "dam"


def test_file_problems_name_the_file(scenes_dir):
    text = SCENE_TOML.replace("viscosity = 0.1", "viscosity = -1.0\nviscosty = 2")
    (scenes_dir / "x.toml").write_text(text)
    assert problems_of("x") == [
        "scenes/x.toml: fluid.viscosity: out of range (got -1.0; expected a number >= 0)",
        "scenes/x.toml: fluid.viscosty: unknown key (did you mean 'viscosity'?)",
    ]


def test_toml_syntax_error_is_one_line(scenes_dir):
    text = SCENE_TOML.replace("spacing = 0.05", "spacing = = 0.05")
    (scenes_dir / "broken.toml").write_text(text)
    found = problems_of("broken")
    assert len(found) == 1
    assert found[0].startswith("scenes/broken.toml: invalid TOML: ") and "line 7" in found[0]
    assert found[0].endswith(": 'spacing = = 0.05'"), found[0]


def test_a_key_given_twice_is_named_by_its_line(scenes_dir):
    """tomllib says only "Cannot overwrite a value"; the line names the key."""
    (scenes_dir / "twice.toml").write_text(SCENE_TOML.replace("spacing = 0.05", "spacing = 0.05\nspacing = 0.04"))
    found = problems_of("twice")
    assert len(found) == 1 and found[0].endswith(": 'spacing = 0.04'"), found


def test_a_byte_order_mark_is_read_past(scenes_dir):
    """Some editors start a UTF-8 file with a byte-order mark, which tomllib reads as an
    invalid statement at line 1."""
    (scenes_dir / "bom.toml").write_bytes(b"\xef\xbb\xbf" + SCENE_TOML.encode("utf-8"))
    assert load_scene("bom").particles.spacing == 0.05
    assert list_scenes() == [("bom", "a small dam break")]


def test_a_toml_error_quotes_its_line_as_tomllib_counts_lines():
    """tomllib counts lines at newlines only, where str.splitlines also breaks at U+2028
    (legal in a TOML comment); a long line is cut."""
    from mrsph.scene.config.loading import _with_line

    text = "# a comment with a \u2028 in it\nspacing = = 1\n"
    assert _with_line("Invalid value (at line 2, column 11)", text).endswith(": 'spacing = = 1'")
    long = "x = [" + "1, " * 100 + "\n"
    quoted = _with_line("Unclosed array (at line 1, column 306)", long)
    assert len(quoted) < 170 and quoted.endswith("…'"), quoted


def test_missing_file(scenes_dir):
    found = problems_of("scenes/none.toml")
    assert found == [
        "scenes/none.toml: no such scene or file (expected a scene name or a path "
        "to a .toml file; available scenes: none in " + str(scenes_dir) + ")"
    ]


def test_resolve_missing_name_lists_scenes(scenes_dir):
    for name in ("dam_break_2d", "wave_3d"):
        (scenes_dir / f"{name}.toml").write_text(SCENE_TOML)
    assert resolve_scene_path("wave_3d") == scenes_dir / "wave_3d.toml"
    with pytest.raises(SceneError) as info:
        resolve_scene_path("dam_brake_2d")
    assert info.value.problems == [
        "dam_brake_2d: no such scene or file, did you mean 'dam_break_2d'? (expected a scene "
        "name or a path to a .toml file; available scenes: dam_break_2d, wave_3d)"
    ]


def test_list_scenes_sorted_with_descriptions(scenes_dir):
    (scenes_dir / "b.toml").write_text(SCENE_TOML)
    (scenes_dir / "a.toml").write_text('description = "first"\n')
    (scenes_dir / "c.toml").write_text("description = \n")
    listed = list_scenes()
    assert [name for name, _ in listed] == ["a", "b", "c"]
    assert listed[0][1] == "first" and listed[1][1] == "a small dam break"
    assert listed[2][1].startswith("(unreadable")


def test_repo_scenes_are_valid():
    """Every scene of scenes/ passes the check (without Taichi: a quick guard beside
    tests/test_scenes.py, which runs them), and the ones the README promises are there."""
    names = [name for name, _ in list_scenes()]
    for want in ("demo_2d", "dam_break_obstacle_2d", "dam_break_obstacle_3d", "region_2d", "region_3d"):
        assert want in names, f"scenes/{want}.toml is missing (found {names})"
    for name in names:
        load_scene(name)


def test_import_is_light():
    code = "import sys, mrsph.scene.config; print('taichi' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == "False", out.stderr


# --------------------------------------------------------------------------------- docs
@pytest.fixture(scope="module")
def scene_docs():
    return load_tool("scene_docs")


def test_docs_tables_match_schema(scene_docs):
    text = (REPO / "docs" / "scenes.md").read_text(encoding="utf-8")
    assert scene_docs.render(text) == text, "docs/scenes.md is out of date: run python3 tools/scene_docs.py"


def test_docs_generator_restores_a_stale_table(scene_docs):
    """The check can fail: a row edited by hand, or a schema key missing from the page, is
    put back by the generator, and the prose outside the markers is kept."""
    text = (REPO / "docs" / "scenes.md").read_text(encoding="utf-8")
    row = "| `viscosity` |"
    assert row in text
    stale = text.replace(row, "| `viscosityy` |", 1)
    assert stale != text and scene_docs.render(stale) == text
    assert scene_docs.markdown_tables() in text
    with pytest.raises(ValueError, match="markers"):
        scene_docs.render(text.replace(scene_docs.END, ""))


def test_docs_example_scene_is_valid():
    text = (REPO / "docs" / "scenes.md").read_text(encoding="utf-8")
    examples = re.findall(r"```toml\n(.*?)```", text, re.S)
    assert examples
    for example in examples:
        load_scene(tomllib.loads(example))


def test_pbf_refuses_an_odd_iteration_count_at_full_relaxation():
    """An odd count of Jacobi iterations at omega near 1 grows the checkerboard mode (the
    error of that mode flips sign each iteration and overshoots): refused in one line
    naming the key, its value and what to use; the rule is pbf's (its package's rules)."""
    base = ['fluid.solver="pbf"', "pbf.iterations=3"]
    with pytest.raises(SceneError) as e:
        load_scene("dam_break_2d", base + ["pbf.over_relaxation=0.9"])
    (line,) = e.value.problems
    assert "pbf.over_relaxation" in line and "0.9" in line and "at most 0.7" in line, line
    load_scene("dam_break_2d", base + ["pbf.over_relaxation=0.7"])
    load_scene("dam_break_2d", ['fluid.solver="pbf"', "pbf.iterations=4", "pbf.over_relaxation=1.0"])
    with pytest.raises(SceneError, match="pbf.min_iterations: above pbf.iterations"):
        load_scene("dam_break_2d", ['fluid.solver="pbf"', "pbf.min_iterations=5"])
    # a count the step's error sets (pbf.min_iterations below pbf.iterations) is odd in some steps
    varies = ['fluid.solver="pbf"', "pbf.iterations=4", "pbf.min_iterations=2"]
    with pytest.raises(SceneError) as e:
        load_scene("dam_break_2d", varies + ["pbf.over_relaxation=0.9"])
    (line,) = e.value.problems
    assert "pbf.over_relaxation" in line and "varies" in line and "0.9" in line and "at most 0.7" in line, line
    load_scene("dam_break_2d", varies + ["pbf.over_relaxation=0.7", "pbf.max_density_error=0.2"])


def test_the_app_reads_its_defaults_from_the_schema():
    """A key a plain-dict scene leaves out reads as the schema's default in the app (one
    place for every default); a given value wins, and a key without a default is None."""
    from mrsph.app.view import scene_setting
    from mrsph.scene.config.schema import default_of

    assert scene_setting({"dim": 2}, "render.width") == default_of("render.width") == 960
    assert scene_setting({"dim": 3}, "fluid.stiffness") == 1000.0
    assert scene_setting({"dim": 2, "pbf": {"substeps": 7}}, "pbf.substeps") == 7
    assert default_of("pbf.substeps") == 20 and default_of("domain.min") is None
    assert scene_setting(None, "run.fps") == 30.0 and scene_setting({}, "stirrers") is None
