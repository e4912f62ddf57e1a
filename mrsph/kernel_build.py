"""Faster kernel builds: Taichi 1.7.4 reads and formats the same source again for every
call site of every ``ti.func`` it inlines; this module makes it remember instead.

Taichi turns a kernel into its IR in Python (``Kernel.materialize``) on the first call
of each kernel of each new object, even when its offline cache then serves the compiled
code. For every ``ti.func`` call it inlines, it reads the function's source again
(``inspect.getsourcelines``), passes each line through ``textwrap.fill``, and for every
AST node it visits, formats a position message with a caret line (``get_pos_info``,
two ``TextWrapper.wrap`` calls a node), kept as the node's debug information. A
2D dam break under dfsph inlines 1,007 function bodies and formats 45,872 positions
for its 18 kernels: 7.8 of the 12.0 s its first step spent building IR (cProfile, warm
offline cache, this 2-core machine; docs/performance.md, "Building the kernels").

:func:`install` memoizes those three, keyed by what they read, so that each is computed
once a process: the source lines by the function object, each line's ``fill`` by the
line, a position message by the function and the node's place and span. The strings
are the ones Taichi would have made, so the IR, its offline-cache key and every error
message are unchanged. Taichi is pinned (requirements.txt); on another version whose
internals differ, :func:`install` leaves Taichi as it is and says so in
:func:`installed`.
"""

from __future__ import annotations

import functools
import textwrap
import types

_state = {"installed": False, "why_not": "not installed yet"}


def installed() -> tuple[bool, str]:
    """(whether the memoization is in place, why not if it is not)."""
    return _state["installed"], _state["why_not"]


def install() -> bool:
    """Memoize Taichi's source reading and position messages (once a process)."""
    if _state["installed"]:
        return True
    try:
        from taichi.lang import kernel_impl
        from taichi.lang.ast import ast_transformer_utils as utils

        context = utils.ASTTransformerContext
        originals = (kernel_impl.getsourcelines, kernel_impl.getsourcefile, kernel_impl.textwrap, context.get_pos_info)
    except (ImportError, AttributeError) as e:
        _state["why_not"] = f"this Taichi's internals differ from 1.7.4's ({e})"
        return False
    lines, source_file, _, position = originals
    kernel_impl.getsourcelines = functools.lru_cache(maxsize=None)(lines)
    kernel_impl.getsourcefile = functools.lru_cache(maxsize=None)(source_file)
    fill = functools.lru_cache(maxsize=None)(textwrap.fill)
    kernel_impl.textwrap = types.SimpleNamespace(fill=fill, dedent=textwrap.dedent)
    context.get_pos_info = _remembered(position)
    _state.update(installed=True, why_not="")
    return True


def _remembered(position):
    """``get_pos_info`` once per function and node span. What it reads: the function
    (its name, file and source lines, themselves fixed by the function), its first line
    and indentation, and the node's type, lines, columns and first body line."""
    made: dict = {}

    def get_pos_info(ctx, node):
        body = getattr(node, "body", None)
        key = (
            ctx.func.func,
            ctx.lineno_offset,
            ctx.indent,
            type(node),
            node.lineno,
            node.end_lineno,
            node.col_offset,
            node.end_col_offset,
            body[0].lineno if isinstance(body, list) and body else None,
        )
        msg = made.get(key)
        if msg is None:
            msg = made[key] = position(ctx, node)
        return msg

    get_pos_info.original = position  # for the test that compares the two
    return get_pos_info
