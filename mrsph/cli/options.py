"""Command-line helpers shared by ``python3 main.py`` (:mod:`mrsph.cli.commands`), its ``bench``
command (:mod:`mrsph.cli.bench`) and ``python -m mrsph.app``: exit codes, argument types that
report a bad value in one line, the parser and help formatter, and the checks that an
output file or directory can be written before a run starts.

The bottom floor of the command line: it imports neither :mod:`mrsph.cli.commands` nor
:mod:`mrsph.cli.bench` (so ``cli -> bench -> options`` and ``app -> options`` hold no circle),
and nothing from Taichi.
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

#: Exit status of ``python3 main.py`` (and of its ``bench`` command): see mrsph.cli.commands.
EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130

#: Simulation per window frame, ms (a string: argparse converts it): with ~30 ms to draw a
#: frame on a CPU (lavapipe), the window stays near 15 frames/s wherever a step takes less
#: than the budget
WINDOW_FRAME_BUDGET_MS = "40"


def threads_arg(text: str):
    """--threads: "auto" or a positive integer."""
    if text == "auto":
        return text
    try:
        return positive_int(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected auto or a positive integer (got {text!r})") from None


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer (got {text!r})") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer (got {value})")
    return value


#: --width/--height: the range of the scene keys render.width/height
PIXELS = (64, 8192)


def pixels_arg(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or not PIXELS[0] <= value <= PIXELS[1]:
        raise argparse.ArgumentTypeError(
            f"expected an integer number of pixels in [{PIXELS[0]}, {PIXELS[1]}] (got {text!r})"
        )
    return value


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number (got {text!r})") from None
    if not 0 < value < math.inf:
        raise argparse.ArgumentTypeError(f"expected a finite positive number (got {text})")
    return value


def fps_arg(text: str) -> float:
    """--fps: a number of frames per second within config.FPS_RANGE."""
    from mrsph.limits import FPS_RANGE

    lo, hi = FPS_RANGE
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not lo <= value <= hi:  # NaN fails too
        raise argparse.ArgumentTypeError(f"expected a number in [{lo:g}, {hi:g}] (got {text})")
    return value


def frame_budget_arg(text: str) -> float | None:
    """--frame-budget: milliseconds >= 0 -> seconds, or None (whole frames) for 0."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (value >= 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"expected a finite number of milliseconds >= 0 (got {text!r})")
    return value / 1000.0 if value > 0 else None


class Parser(argparse.ArgumentParser):
    """Reports a bad argument in one line (argparse prints the whole usage block first)."""

    def error(self, message):
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


class HelpFormatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """Keeps the epilog's line breaks; appends "(default: X)" where the help has none."""

    def _get_help_string(self, action):
        text = action.help or ""
        if "(default" in text or action.default in (None, argparse.SUPPRESS):
            return text
        if action.default is False:
            return text + " (default: off)"
        return text + " (default: %(default)s)"


def dir_problem(flag: str, path: Path) -> str | None:
    """Why files cannot be written into directory ``path`` (made if missing), or None."""
    if path.exists() and not path.is_dir():
        return f"error: {flag} {path}: exists and is not a directory"
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        return f"error: {flag} {path}: cannot make the directory ({e.strerror or e})"
    if not os.access(path, os.W_OK | os.X_OK):
        return f"error: {flag} {path}: the directory is not writable"
    return None


def file_problem(flag: str, path: Path) -> str | None:
    """Why file ``path`` cannot be written (its directory made if missing), or None."""
    if path.is_dir():
        return f"error: {flag} {path}: is a directory (expected a file name)"
    problem = dir_problem(flag, path.parent) if str(path.parent) not in ("", ".") else None
    if problem:
        return problem
    existed = path.exists()
    try:
        with open(path, "ab"):
            pass
        if not existed:
            path.unlink()
    except OSError as e:
        return f"error: {flag} {path}: cannot write the file ({e.strerror or e})"
    return None
