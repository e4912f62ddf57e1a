"""Typed, frozen parameters: each table of a validated scene as a frozen dataclass made
from its schema (``scene.params.fluid.rest_density``, ``scene.params.obstacles[0].min``),
so that each part of a simulation is handed the values it reads, typed as the schema
declares them, and cannot change them (a live change makes a new scene, and new params).

The classes are built from the schema once per table (and per variant of a table with a
switch, such as an obstacle's shape), so that a key is declared in one place only.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from .schema import SCHEMA, Array, Key, Table

_TYPES = {"float": float, "int": int, "bool": bool, "str": str, "choice": str}
_CLASSES: dict[str, type] = {}


def _type(spec) -> Any:
    if isinstance(spec, Key):
        return _TYPES.get(spec.kind, tuple)  # vec, vec3, path: tuples of floats
    return tuple if isinstance(spec, Array) else object


def _class(path: str, keys: dict) -> type:
    """The frozen dataclass of table ``path`` with these keys (schema entries by name)."""
    name = path or "scene"
    if name not in _CLASSES:
        title = "".join(p.capitalize() for p in name.replace(".", "_").split("_")) + "Params"
        fields = [(k, _type(spec)) for k, spec in keys.items()]
        _CLASSES[name] = dataclasses.make_dataclass(title, fields, frozen=True)
    return _CLASSES[name]


def freeze(spec, value, path: str = ""):
    """``value`` (a validated scene's data, or part of it) as frozen params of ``spec``."""
    if isinstance(spec, Array):
        return tuple(freeze(spec.item, item, path) for item in value)
    if not isinstance(spec, Table) or value is None:
        return value
    keys = dict(spec.keys)
    while spec.switch:  # the chosen variant's keys join the table's
        variant = value[spec.switch]
        spec = spec.variants[variant]
        keys.update(spec.keys)
        path = f"{path}.{variant}" if path else variant
    return _class(path, keys)(**{k: freeze(sub, value.get(k), f"{path}.{k}" if path else k) for k, sub in keys.items()})


def Params(data: dict):
    """The frozen params of a whole validated scene (``SCHEMA``'s tables)."""
    return freeze(SCHEMA, data)
