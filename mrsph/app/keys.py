"""The window's keys and mouse, in one table: the README's "Controls (window)" table,
the help panel (``h``), ``python3 main.py keys`` and ``python3 main.py --help`` are
all made from :data:`KEYS` (tests/test_cli.py holds the README to it).

Taichi 1.7.4's GGUI reports letters, arrows, space, Tab, Escape, Shift and the mouse's
buttons, but no digits, punctuation or wheel, so every action has a letter (or a HUD
button). Texts are Markdown (backticks around key names); the plain forms drop them.
"""

from __future__ import annotations

import textwrap
from typing import NamedTuple


class Key(NamedTuple):
    keys: str  # what to press or drag
    action: str  # what it does


KEYS = (
    Key("left drag", "push the water along the drag (and refine it there)"),
    Key("right drag (2D), shift + left drag", "pull the water toward the cursor"),
    Key("`q` / `e`", "shrink / grow the mouse's reach (the white circle)"),
    Key("`w` / `t`", "water view: the fluid as a surface (2D a body of water, 3D a lit mesh) / tint it by colour mode"),
    Key("space / `n` / `r`", "pause / one frame / reset"),
    Key("Tab / shift + Tab, or a button in the help panel", "next / previous scene, that scene"),
    Key("`c` / `v`", "colour by level → kind → speed → density / show virtual particles"),
    Key(
        "`s`, or the HUD's solver button",
        "next pressure solver (`fluid.solver`'s choices, in turn): the scene restarts with it",
    ),
    Key("`h` / `u`", "help panel / hide the HUD"),
    Key("`p`", "screenshot, into `out/screenshots/` (under the current directory)"),
    Key("3D: right drag or arrows; middle drag; `z` / `x`; `f`", "orbit; pan; zoom in / out; frame the domain again"),
    Key("Esc", "quit"),
)


def plain(text: str, ascii_only: bool = False) -> str:
    """A Markdown text of the table without its backticks (``ascii_only``: and its
    arrows as ASCII, for ImGui's font, which has Latin-1 only)."""
    text = text.replace("`", "")
    return text.replace("→", "->").replace("↔", "<->") if ascii_only else text


def markdown_table() -> str:
    """The README's table (header and rows, no trailing newline)."""
    rows = ["| input | action |", "|---|---|"]
    rows += [f"| {k.keys} | {k.action} |" for k in KEYS]
    return "\n".join(rows)


def text_table(width: int = 100, indent: int = 2, key_chars: int = 30, ascii_only: bool = False) -> str:
    """The table as plain text in two columns (keys ``key_chars`` wide), both wrapped
    so that no line passes ``width`` characters."""
    out = []
    for k in KEYS:
        keys = textwrap.wrap(plain(k.keys, ascii_only), key_chars - 2)
        action = textwrap.wrap(plain(k.action, ascii_only), max(width - indent - key_chars, 20))
        for i in range(max(len(keys), len(action))):
            left = keys[i] if i < len(keys) else ""
            right = action[i] if i < len(action) else ""
            out.append((" " * indent + f"{left:<{key_chars}}{right}").rstrip())
    return "\n".join(out)
