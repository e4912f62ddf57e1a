"""Scene files: strict, typed TOML with every problem reported at once.

A scene is a TOML file in ``scenes/``; docs/scenes.md lists every key (type, unit,
default, meaning). ``load_scene`` parses it, applies ``--set KEY=VALUE`` overrides,
checks each key against ``SCHEMA`` (type, range, vector length, unknown keys with a
did-you-mean hint), then the cross-field rules (fluid inside the domain and outside the
obstacles, levels that exist, a capacity that holds the fluid, the pressure solver's
own), and raises one ``SceneError`` holding all problems, one line each:
``<file>: <key>: <what is wrong> (got <value>; expected <what>)``. A loaded ``Scene``
carries its values typed and frozen (``scene.params``). Pure Python, no Taichi, nothing
done at import.

- ``schema.py``: the keys (``Key``, ``Table``, ``Array``, ``SCHEMA``);
- ``checks.py``: one value against its key, the problems' wording (``Checker``);
- ``rules.py``: the rules between keys (``validate``);
- ``loading.py``: files, overrides, ``Scene``, ``load_scene``, the shipped scenes;
- ``params.py``: the frozen, typed parameters.
"""

from .checks import OPTION_FLAG, SceneError
from .loading import SCENES_DIR, Node, Scene, list_scenes, load_scene, resolve_scene_path
from .params import Params, freeze
from .rules import CAPACITY_MARGIN, CAPACITY_SLACK, EMIT_HORIZON_S, emitter_disc, mass_exact
from .schema import REQUIRED, SCHEMA, Array, Key, Table

__all__ = [
    "CAPACITY_MARGIN",
    "CAPACITY_SLACK",
    "EMIT_HORIZON_S",
    "OPTION_FLAG",
    "REQUIRED",
    "SCENES_DIR",
    "SCHEMA",
    "Array",
    "Key",
    "Node",
    "Params",
    "Scene",
    "SceneError",
    "Table",
    "emitter_disc",
    "freeze",
    "list_scenes",
    "load_scene",
    "mass_exact",
    "resolve_scene_path",
]
