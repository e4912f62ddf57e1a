"""The command line: ``python3 main.py [SCENE] [options]``, ``python3 main.py list``,
``python3 main.py keys``, ``python3 main.py bench ...``.

Without ``--headless`` an interactive window opens when a display is available;
otherwise a short video is recorded instead. ``--headless`` runs a fixed number of
frames and can dump particles and statistics; ``--out`` records a video.

Exit status: 0 done; 1 the simulation failed (NaN, blow-up); 2 a usage or scene error
(nothing was run); 130 interrupted (Ctrl-C).
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
import warnings
from pathlib import Path

from .. import __version__
from .options import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_OK,
    EXIT_USAGE,
    WINDOW_FRAME_BUDGET_MS,
    HelpFormatter,
    Parser,
    dir_problem,
    file_problem,
    fps_arg,
    frame_budget_arg,
    pixels_arg,
    positive_int,
    threads_arg,
)

#: Frames recorded when no window can open and no --frames was given (2 s at 30 fps:
#: about a minute on a 2-core CPU, long enough to see the fluid move and refine).
FALLBACK_FRAMES = 60
#: Where that fallback recording goes, relative to the working directory.
FALLBACK_DIR = Path("out")
WINDOW_SIZE = (1280, 720)
PREFERRED_DEFAULT_SCENES = ("demo_2d", "dam_break_2d")
NO_END = "error: a headless run needs an end: pass --frames N (or set run.frames in the scene)"


def _default_scene() -> str:
    from mrsph.scene.config import SCENES_DIR

    for name in PREFERRED_DEFAULT_SCENES:
        if (SCENES_DIR / f"{name}.toml").is_file():
            return name
    return PREFERRED_DEFAULT_SCENES[-1]


def build_parser() -> argparse.ArgumentParser:
    from mrsph.app.keys import text_table
    from mrsph.io.output import FORMATS

    parser = Parser(
        prog="python3 main.py",
        description="mrsph: adaptive-resolution SPH fluids in Taichi.\n"
        "Opens an interactive window on SCENE (or, with no display, records a\n"
        "short video of it); --headless runs it without a window.",
        epilog="commands:\n"
        "  python3 main.py list          the scenes in scenes/ with a one-line description\n"
        "  python3 main.py keys          the window's keys and mouse (below)\n"
        "  python3 main.py bench ...     benchmarks (python3 main.py bench --help)\n"
        "\nexamples:\n"
        "  python3 main.py dam_break_2d\n"
        "  python3 main.py dam_break_2d --headless --frames 60 --dump out/dump\n"
        "  python3 main.py pool_3d --out out/pool.mp4 --frames 150\n"
        "  python3 main.py dam_break_obstacle_2d --set fluid.viscosity=2.0 --set adaptivity.enabled=false\n"
        "\nexit status: 0 done, 1 the simulation failed, 2 usage or scene error, "
        "130 interrupted\n"
        "\nthe window's keys and mouse:\n" + text_table(),
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "scene",
        nargs="?",
        metavar="SCENE",
        default=_default_scene(),
        help="scene name from scenes/ or a path to a .toml file",
    )
    parser.add_argument(
        "--arch",
        choices=("auto", "cpu", "gpu"),
        default="auto",
        help="Taichi backend; auto takes a CUDA/Metal GPU if there is one",
    )
    parser.add_argument(
        "--threads",
        type=threads_arg,
        default="auto",
        metavar="N",
        help="CPU threads for the cpu backend, or auto: one thread pinned to "
        "one core for scenes that start under 12k particles in 2D, 4k in "
        "3D (Taichi's per-loop thread wake-up costs more than it saves "
        "there), else all cores (default: auto)",
    )
    parser.add_argument("--version", action="version", version=f"mrsph {__version__}")
    parser.add_argument(
        "--headless", action="store_true", help="no window: run --frames frames (or run.frames), then stop"
    )
    parser.add_argument(
        "--frames",
        type=positive_int,
        default=None,
        metavar="N",
        help="frames to run (headless: N frames simulated, N + 1 states "
        "dumped with t = 0) or record (N video frames, the first at t = 0) "
        "(default: the scene's run.frames; "
        f"{FALLBACK_FRAMES} for the video made when no window can open)",
    )
    parser.add_argument(
        "--out",
        default=None,
        metavar="FILE",
        help="record a video instead: .mp4, .gif, or a directory of PNGs "
        "(its frame_*.png of an earlier run are removed first) "
        "(default: no recording)",
    )
    parser.add_argument(
        "--width",
        type=pixels_arg,
        default=None,
        metavar="PX",
        help=f"image width (default: the scene's render.width; the window {WINDOW_SIZE[0]})",
    )
    parser.add_argument(
        "--height",
        type=pixels_arg,
        default=None,
        metavar="PX",
        help=f"image height (default: the scene's render.height; the window {WINDOW_SIZE[1]})",
    )
    parser.add_argument(
        "--fps",
        type=fps_arg,
        default=None,
        help="frames per second of the recorded video; a frame still simulates 1/run.fps, so another "
        "rate plays the fluid faster or slower (--set run.fps=N changes both) (default: the scene's run.fps)",
    )
    parser.add_argument(
        "--frame-budget",
        type=frame_budget_arg,
        default=WINDOW_FRAME_BUDGET_MS,
        metavar="MS",
        help="window only: simulate until the first step that "
        "ends past MS milliseconds of wall time, then draw; where a frame's "
        "simulated time (1/run.fps) takes longer, the fluid runs in slow "
        "motion instead of the window freezing between frames; 0 = whole "
        f"frames always (default: {WINDOW_FRAME_BUDGET_MS})",
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        dest="overrides",
        help="override a scene key, value as TOML (repeatable), e.g. --set fluid.viscosity=2.0 (default: none)",
    )
    parser.add_argument(
        "--dump",
        default=None,
        metavar="DIR",
        help="write every frame's particles and a stats.csv row to DIR "
        "(frame files of an earlier run there are removed first) "
        "(default: no dump)",
    )
    parser.add_argument(
        "--dump-format",
        choices=FORMATS,
        default="npz",
        help="format of the frame files: npz, ply (binary point cloud), vtk (.vtu) or obj (the water's surface mesh)",
    )
    parser.add_argument(
        "--quiet",
        action="store_true",
        help="no progress bar and no summary line; errors, warnings and notices still show",
    )
    return parser


# ----------------------------------------------------------------------------- messages
def _err(line: str) -> None:
    from tqdm import tqdm

    tqdm.write(line, file=sys.stderr)


def _show_warning(default):
    """A warnings.showwarning that prints RuntimeWarnings as one line, no source line."""

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, RuntimeWarning):
            _err(f"warning: {message}")
        else:
            default(message, category, filename, lineno, file, line)

    return show


# ----------------------------------------------------------------------------- commands
def _cmd_list(argv) -> int:
    from mrsph.scene.config import list_scenes

    if argv and argv[0] in ("-h", "--help"):
        print("usage: python3 main.py list\n\nThe scenes in scenes/, each with its description.")
        return EXIT_OK
    if argv:
        print(
            f"python3 main.py list: error: unrecognized arguments: {' '.join(argv)} (list takes none)", file=sys.stderr
        )
        return EXIT_USAGE
    scenes = list_scenes()
    if not scenes:
        from mrsph.scene.config import SCENES_DIR

        print(f"no scenes in {SCENES_DIR}", file=sys.stderr)
        return EXIT_OK
    width = max(len(name) for name, _ in scenes)
    for name, description in scenes:
        print(f"{name:<{width}}  {description}")
    return EXIT_OK


def _cmd_keys(argv) -> int:
    from mrsph.app.keys import markdown_table, text_table

    if argv and argv[0] in ("-h", "--help"):
        print("usage: python3 main.py keys [--markdown]\n")
        print("The window's keys and mouse (--markdown: as the README's table).")
        return EXIT_OK
    if argv not in ([], ["--markdown"]):
        print(
            f"python3 main.py keys: error: unrecognized arguments: {' '.join(argv)} (keys takes only --markdown)",
            file=sys.stderr,
        )
        return EXIT_USAGE
    print(markdown_table() if argv else text_table())
    return EXIT_OK


def _cmd_bench(argv) -> int:
    if importlib.util.find_spec("mrsph.cli.bench") is None:
        print("mrsph: benchmarks are not available in this version (mrsph/cli/bench/ is missing)", file=sys.stderr)
        return EXIT_USAGE
    from . import bench

    status = bench.main(list(argv))
    return EXIT_OK if status is None else int(status)


def _out_kind_problem(out: str) -> str | None:
    path = Path(out)
    if path.suffix.lower() in (".mp4", ".gif"):
        return file_problem("--out", path)
    if path.suffix == "" or path.is_dir():
        return dir_problem("--out", path)
    return (
        f"error: --out {out}: cannot tell what to write (expected a path ending in .mp4 "
        f"or .gif, or a directory for PNG frames)"
    )


def _same_path_problem(out: str, dump: str) -> str | None:
    """--out and --dump at one path, or the dump folder under the recording's file: each
    would find the other's output in its way only once the run has been made."""
    o, d = Path(out).resolve(), Path(dump).resolve()
    if o == d:
        return f"error: --dump {dump}: the path of --out {out} (expected a directory of its own)"
    if o.suffix.lower() in (".mp4", ".gif") and o in d.parents:
        return (
            f"error: --dump {dump}: inside --out {out}, the file the recording writes (expected a directory of its own)"
        )
    return None


def _os_error_line(e: OSError) -> str:
    """One line for an output that failed mid-run. imageio's message for a video encoder
    that stopped carries the encoder's whole command; the encoder has printed its own reason."""
    text = str(e).strip()
    first = text.splitlines()[0] if text else type(e).__name__
    if "FFMPEG COMMAND" in text:
        return f"the video encoder (ffmpeg) stopped ({first}); its own message is above"
    return first


class _Dumper:
    """Frame files and stats.csv rows for --dump, one per rendered frame."""

    def __init__(self, directory, fmt, dim, levels):
        from mrsph.io.output import DUMP_SUFFIXES, StatsWriter, clear_frames

        self.directory, self.fmt, self.dim = Path(directory), fmt, dim
        clear_frames(self.directory, DUMP_SUFFIXES)  # of any format: all are ours
        self.stats = StatsWriter(self.directory / "stats.csv", dim, levels)
        self.last_row: dict | None = None

    def dump(self, snap) -> None:
        from mrsph.io.output import write_frame

        parts = {"x": snap.x, "v": snap.v, "m": snap.m, "rho": snap.rho, "level": snap.level, "kind": snap.kind}
        if snap.p is not None:  # a stand-in without a pressure dumps zeros
            parts["p"] = snap.p
        write_frame(self.directory, snap.frame, parts, self.dim, self.fmt, (snap.domain_min, snap.domain_max))
        self.stats.write(snap.stats)
        self.last_row = snap.stats

    def close(self) -> None:
        self.stats.close()


class _DumpingSim:
    """Forwards to a Simulation; dumps every snapshot taken (what the recorder renders)."""

    def __init__(self, sim, dumper: _Dumper):
        self._sim, self._dumper = sim, dumper

    def snapshot(self, *a, **kw):
        snap = self._sim.snapshot(*a, **kw)
        self._dumper.dump(snap)
        return snap

    def __getattr__(self, name):
        return getattr(self._sim, name)


def _make_sim(scene, args):
    from mrsph import runtime
    from mrsph.simulation import Simulation

    sim = Simulation(scene, arch=args.arch, threads=runtime.auto_threads(scene, args.threads))
    notice = runtime.notice()
    if notice:
        _err(f"mrsph: {notice}")
    return sim


def _run_headless(sim, frames: int, args) -> int:
    from tqdm import tqdm

    dumper = _Dumper(args.dump, args.dump_format, sim.dim, sim.levels) if args.dump else None
    steps = 0
    t0 = time.perf_counter()
    try:
        if dumper:
            dumper.dump(sim.snapshot())
        with tqdm(
            total=frames,
            file=sys.stderr,
            disable=args.quiet,
            unit="frame",
            desc=sim.scene.name,
            dynamic_ncols=True,
            leave=False,
        ) as bar:
            for _ in range(frames):
                steps += sim.advance_frame()
                if dumper:
                    dumper.dump(sim.snapshot())
                bar.update(1)
    finally:
        if dumper:
            dumper.close()
    wall = time.perf_counter() - t0
    row = dumper.last_row if dumper else sim.stats()
    if not args.quiet:
        where = (
            f"; dumped to {args.dump}"
            if args.dump
            else "; nothing written (--dump DIR keeps the frames, --out FILE a video)"
        )
        print(
            f"{sim.scene.name}: {frames} frame{'s' if frames != 1 else ''}, {sim.time:.4g} s simulated in {wall:.3g} s "
            f"wall ({steps} steps); {row['n_real']} real / {row['n_virtual']} virtual "
            f"particles, total mass {row['total_mass']:.6g} kg{where}"
        )
    return EXIT_OK


def _record(sim, out, frames: int, args) -> Path:
    from mrsph.app.record import record

    if Path(out).is_file():
        _err(f"mrsph: {out} exists; it is replaced")
    target = sim
    dumper = _Dumper(args.dump, args.dump_format, sim.dim, sim.levels) if args.dump else None
    if dumper:
        target = _DumpingSim(sim, dumper)
    try:
        return record(target, out, frames, width=args.width, height=args.height, fps=args.fps, progress=not args.quiet)
    finally:
        if dumper:
            dumper.close()


def _run_window_or_video(scene, args) -> int:
    from mrsph.app import ahead
    from mrsph.app.window import NoDisplay, run_window
    from mrsph.scene.config import SCENES_DIR, list_scenes, load_scene

    try:
        ahead.count()
    except ValueError as e:
        _err(f"mrsph: {e}")
        return EXIT_USAGE
    notes = []  # said once the window opens: a recording does take them
    if args.dump:
        notes.append("mrsph: --dump applies to headless runs and recordings; the window does not dump")
    if args.frames is not None:
        notes.append(
            "mrsph: --frames applies to headless runs and recordings; the window runs "
            "until it is closed (add --headless to run N frames)"
        )
    if args.fps is not None:
        notes.append("mrsph: --fps applies to recordings; the window simulates 1/run.fps a frame (--set run.fps=N)")
    names = [name for name, _ in list_scenes()]
    # the window offers the scenes of scenes/ by name; a scene from elsewhere by path
    own = Path(scene.path).resolve() == (SCENES_DIR / f"{scene.name}.toml").resolve()
    first = scene.name if own else str(scene.path)
    if first not in names:
        names = [first] + names

    # one thread count for the window's life, as --threads resolves it for the first
    # scene: another count re-initialises Taichi, which frees the window's fields
    # under it (a scene switch from a small scene to a large one crashed the window)
    from mrsph import runtime

    fixed = argparse.Namespace(**{**vars(args), "threads": runtime.auto_threads(scene, args.threads)})

    def make_sim(name, overrides=None):
        # --set applies to every scene the window opens; the window's own overrides
        # (the refinement checkbox) come on top
        s = load_scene(name, args.overrides)
        if overrides:
            s = s.with_overrides(overrides)
        return _make_sim(s, fixed)

    try:
        run_window(
            make_sim,
            first,
            names,
            args.width or WINDOW_SIZE[0],
            args.height or WINDOW_SIZE[1],
            frame_budget=args.frame_budget,
            opened=lambda: [_err(note) for note in notes],
        )
        return EXIT_OK
    except NoDisplay as e:
        why = str(e)
    frames = args.frames or FALLBACK_FRAMES
    out = FALLBACK_DIR / f"{scene.name}.mp4"
    problem = args.dump and dir_problem("--dump", Path(args.dump))
    if problem:
        _err(problem)
        return EXIT_USAGE
    _err(f"mrsph: no window ({why}); recording {frames} frames to {out} instead")
    from mrsph.simulation import SimulationError

    sim = _make_sim(scene, args)
    try:
        path = _record(sim, out, frames, args)
    except SimulationError:
        raise
    except (OSError, RuntimeError) as e:
        out = out.with_suffix(".gif")
        why = _os_error_line(e) if isinstance(e, OSError) else f"{type(e).__name__}: {e}"
        _err(f"mrsph: writing mp4 failed ({why}); writing {out} instead")
        sim.reset()
        path = _record(sim, out, frames, args)
    print(path)
    return EXIT_OK


def _run(args) -> int:
    from mrsph.scene.config import load_scene

    scene = load_scene(args.scene, args.overrides)
    # a window does not dump: its --dump folder is made only once no window opens
    dumps = args.dump and (args.headless or args.out)
    for problem in (
        args.out and dumps and _same_path_problem(args.out, args.dump),
        args.out and _out_kind_problem(args.out),
        dumps and dir_problem("--dump", Path(args.dump)),
    ):
        if problem:
            _err(problem)
            return EXIT_USAGE
    frames = args.frames if args.frames is not None else int(scene.get("run.frames"))
    if args.headless or args.out:
        if frames < 1:
            _err(NO_END)
            return EXIT_USAGE
        unused = [f"--{k}" for k in ("width", "height", "fps") if getattr(args, k) is not None]
        if unused and not args.out:
            verb = "applies" if len(unused) == 1 else "apply"
            _err(f"mrsph: {', '.join(unused)} {verb} to recordings (--out); a headless run renders nothing")
        sim = _make_sim(scene, args)
        if args.out:
            print(_record(sim, args.out, frames, args))
            return EXIT_OK
        return _run_headless(sim, frames, args)
    return _run_window_or_video(scene, args)


def main(argv=None) -> int:
    """Run the command line; returns the exit status (see the module docstring)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "help":  # "help" and "help bench" read as --help and bench --help
        argv = [*argv[1:2], "--help"]
    if argv and argv[0] == "list":
        return _cmd_list(argv[1:])
    if argv and argv[0] == "keys":
        return _cmd_keys(argv[1:])
    if argv and argv[0] == "bench":
        return _cmd_bench(argv[1:])
    from mrsph.scene.config import SceneError

    args = build_parser().parse_args(argv)
    if args.scene in ("list", "keys", "bench") and not Path(args.scene).exists():
        # "--quiet list": the commands come first, before any option
        _err(
            f"python3 main.py: error: '{args.scene}' is a command: it comes first "
            f"(python3 main.py {args.scene} ...), before any option"
        )
        return EXIT_USAGE
    with warnings.catch_warnings():
        warnings.simplefilter("once", RuntimeWarning)
        warnings.showwarning = _show_warning(warnings.showwarning)
        try:
            return _run(args)
        except SceneError as e:
            for line in e.problems:
                _err(line)
            return EXIT_USAGE
        except KeyboardInterrupt:
            _err("mrsph: interrupted")
            return EXIT_INTERRUPTED
        except OSError as e:
            # writing the output failed mid-run (disk full, the video encoder died, ...)
            _err(f"error: {_os_error_line(e)}")
            return EXIT_FAILED
        except Exception as e:
            # only a SimulationError is expected here; the solver is imported by then
            solver = sys.modules.get("mrsph.simulation")
            if solver is not None and isinstance(e, solver.SimulationError):
                _err(f"error: {e}")
                return EXIT_FAILED
            raise
