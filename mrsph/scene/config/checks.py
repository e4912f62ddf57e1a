"""Checking one scene against the schema: each value's type, range and length, unknown
keys with a did-you-mean hint, every problem gathered as one line
``<file>: <key>: <what is wrong> (got <value>; expected <what>)`` (``Checker``)."""

from __future__ import annotations

import difflib
import json
import math
import numbers

from .schema import REQUIRED, Array, Key, Table


class SceneError(Exception):
    """Everything wrong with a scene; ``problems`` has one line per problem."""

    def __init__(self, problems: list[str] | str):
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        super().__init__("\n".join(self.problems))


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


def fmt_value(v, typed: bool = False) -> str:
    """A value as TOML writes it, shortened; ``typed`` appends its TOML type."""
    if isinstance(v, bool):
        s = "true" if v else "false"
    elif isinstance(v, str):
        s = json.dumps(v)
    elif isinstance(v, (list, tuple)):
        s = "[" + ", ".join(fmt_value(x) for x in v) + "]"
    elif isinstance(v, dict):
        s = "{" + ", ".join(f"{k} = {fmt_value(x)}" for k, x in v.items()) + "}"
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
            close = difflib.get_close_matches(v, k.choices, 1)
            raise _Bad("unknown choice" + (f", did you mean '{close[0]}'?" if close else ""))
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


def all_keys(t: Table) -> dict:
    """Every key a table may hold, whatever its variant."""
    keys = dict(t.keys)
    for variant in t.variants.values():
        keys.update(all_keys(variant))
    return keys


def hint(name: str, candidates) -> str:
    close = difflib.get_close_matches(name, list(candidates), 1)
    if close:
        return f"did you mean '{close[0]}'?"
    return "expected one of " + ", ".join(f"'{c}'" for c in candidates)


# ------------------------------------------------------------------------- validation
#: how problems name an override given as "KEY=VALUE" text, as the command line does
OPTION_FLAG = "--set"


class Checker:
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
            self.add(key, "wrong type", fmt_value(raw, True), "a table")
            return None
        out: dict = {}
        allowed = self.fill(spec, raw, key, dim, out)
        for name in raw:
            if allowed is not None and name not in allowed:
                self.add(f"{key}.{name}" if key else name, "unknown key", note=hint(name, sorted(allowed)))
        lo, hi = out.get("min"), out.get("max")
        if lo is not None and hi is not None and any(b <= a for a, b in zip(lo, hi)):
            self.add(f"{key}.max", "not above min", fmt_value(hi), f"every component > min = {fmt_value(lo)}")
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
                    self.add(k, "wrong type", fmt_value(items, True), f"an array of tables [[{k}]]")
                    self.broken.add(k)
                    items = []
                if sub.max_items and len(items) > sub.max_items:
                    self.add(k, "too many entries", str(len(items)), f"at most {sub.max_items}")
                out[name] = [self.table(sub.item, item, f"{k}.{i}", dim) for i, item in enumerate(items)]
            elif name in raw:
                try:
                    out[name] = _convert(sub, raw[name], dim)
                except _Bad as bad:
                    self.add(k, bad.what, fmt_value(raw[name], bad.typed), _expected(sub, dim))
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
