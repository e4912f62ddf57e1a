"""``python -m mrsph.app [scene]``: open the interactive window on a scene.

The project's ``main.py`` is the full command line; this entry point exists so the app
can be started (and smoke-tested) on its own. ``--fake 2`` or ``--fake 3`` runs the
stand-in simulation of the tests (``tests/fake_app.py`` of a checkout) instead of the
solver.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mrsph.cli.options import WINDOW_FRAME_BUDGET_MS, frame_budget_arg


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m mrsph.app", description=__doc__.splitlines()[0])
    parser.add_argument("scene", nargs="?", help="scene name or .toml path (default: the first scene)")
    parser.add_argument("--arch", default="cpu", choices=("cpu", "gpu", "auto"), help="Taichi backend")
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--height", type=int, default=720)
    parser.add_argument("--fake", type=int, choices=(2, 3), help="use the stand-in simulation")
    parser.add_argument("--fake-build-s", type=float, default=0.0, metavar="S",
                        help="the stand-in takes S seconds to build, as a real scene would (tests)")
    parser.add_argument("--frame-budget", type=frame_budget_arg, default=WINDOW_FRAME_BUDGET_MS,
                        metavar="MS", help="milliseconds of simulation per drawn frame "
                        f"(default: {WINDOW_FRAME_BUDGET_MS}; 0 = whole frames)")
    args = parser.parse_args(argv)

    from .window import run_window

    if args.fake:
        tests = Path(__file__).resolve().parents[2] / "tests"
        if not (tests / "fake_app.py").is_file():
            print(f"python -m mrsph.app: --fake runs the tests' stand-in, {tests / 'fake_app.py'}, "
                  "which only a checkout has", file=sys.stderr)
            return 2
        sys.path.insert(0, str(tests))
        from fake_app import FakeSimulation

        def make_sim(name, overrides=None):
            return FakeSimulation(dim=args.fake, build_s=args.fake_build_s)
        run_window(make_sim, f"fake_{args.fake}d", [f"fake_{args.fake}d"], args.width, args.height,
                   args.frame_budget)
        return 0

    from mrsph.scene.config import SceneError, list_scenes, load_scene
    from mrsph.simulation import Simulation
    names = [name for name, _ in list_scenes()]
    scene = args.scene or (names[0] if names else None)
    if scene is None:
        print("mrsph: no scenes found; give a scene file", file=sys.stderr)
        return 2

    def make_sim(name, overrides=None):
        return Simulation(load_scene(name, overrides), arch=args.arch)
    try:
        run_window(make_sim, scene, names, args.width, args.height, args.frame_budget)
    except (SceneError, RuntimeError) as e:
        print(f"mrsph: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
