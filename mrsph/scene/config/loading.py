"""Loading a scene: the TOML file or a dict, ``--set KEY=VALUE`` overrides applied and
checked against the schema, then validated (``rules.validate``) into a ``Scene``; the
scene files shipped in scenes/."""

from __future__ import annotations

import copy
import difflib
import re
import tomllib
from pathlib import Path
from typing import Any

from .checks import OPTION_FLAG, SceneError, all_keys, fmt_value, hint
from .params import Params
from .rules import lattice_count, validate
from .schema import SCHEMA, Array, Key

# The scene files: the checkout's scenes/ at the repository's root, or, in an installed
# package (pip install .), the copy pyproject.toml puts in mrsph/scenes.
_PACKAGE = Path(__file__).resolve().parents[2]
SCENES_DIR = next(
    (d for d in (_PACKAGE.parent / "scenes", _PACKAGE / "scenes") if d.is_dir()), _PACKAGE.parent / "scenes"
)


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
                f"{OPTION_FLAG} {item}: not KEY=VALUE (got {fmt_value(item)}; expected for example fluid.viscosity=0.2)"
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
        keys = all_keys(spec)
        if part not in keys:
            problems.append(f"{flag} {key}: unknown key ({hint(part, keys)})")
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
            raise KeyError(f"{key}: no such key ({hint(name, sorted(self._data))})")
        return _wrap(self._data[name], f"{self._key}.{name}" if self._key else name)

    def __contains__(self, name: str) -> bool:
        return name in self._data

    def __repr__(self) -> str:
        return f"Node({self._key!r}: {fmt_value(self._data)})"


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
        self.params = Params(data)  # every table typed and frozen (params.py)

    def get(self, dotted: str):
        """The value at a dotted key ("fluid.viscosity", "fluid.blocks.0.min")."""
        node = self.data
        for part in dotted.split("."):
            if isinstance(node, dict) and part in node:
                node = node[part]
            elif isinstance(node, list) and part.isdigit() and int(part) < len(node):
                node = node[int(part)]
            else:
                why = f" ({hint(part, sorted(node))})" if isinstance(node, dict) else ""
                raise KeyError(f"{dotted}: no such key{why}")
        return node

    def with_overrides(self, overrides) -> Scene:
        """A re-validated copy with overrides applied to the scene as written."""
        return _build(self._raw, self.path, self.name, overrides)

    def estimate_particles(self) -> int:
        """Lattice points (cell centres at spacing s0) inside all fluid blocks."""
        return lattice_count(self.data["fluid"]["blocks"], self.data["particles"]["spacing"])

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
    data, found = validate(raw, label, applied, flag)
    if applied and found:
        # a problem the scene has without the --set values too is the scene's own: it is
        # not labelled "with --set ..." (which says an override may have caused it)
        _, own = validate(copy.deepcopy(original), label, [])
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
            description = tomllib.loads(read_toml_text(path)).get("description", "")
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
    if Path(text).is_dir():
        raise SceneError(f"{text}: a directory (expected a scene name or a path to a .toml file)")
    names = [name for name, _ in list_scenes()]
    close = difflib.get_close_matches(Path(text).stem, names, 1)
    why = f", did you mean '{close[0]}'?" if close else ""
    available = ", ".join(names) or f"none in {SCENES_DIR}"
    raise SceneError(
        f"{text}: no such scene or file{why} (expected a scene name or a path "
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
        text = read_toml_text(path)
        raw = tomllib.loads(text)
    except (OSError, UnicodeDecodeError) as e:
        raise SceneError(f"{label}: cannot read the file ({e})") from None
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{label}: invalid TOML: {_with_line(str(e), text)}") from None
    return _build(raw, str(path), path.stem, overrides)


def read_toml_text(path: Path) -> str:
    """A scene file's text; a byte-order mark, which some editors write, is no error."""
    return path.read_text(encoding="utf-8-sig")


def _with_line(message: str, text: str, width: int = 120) -> str:
    """tomllib's message with the line it points at, which names the key (a key given
    twice reads "Cannot overwrite a value" and no more). Lines as tomllib counts them:
    at newlines only."""
    at = re.search(r"at line (\d+)", message)
    lines = text.split("\n")
    if at is None or not 1 <= int(at.group(1)) <= len(lines):
        return message
    line = lines[int(at.group(1)) - 1].strip()
    if len(line) > width:
        line = line[: width - 1] + "…"
    return f"{message}: {line!r}"
