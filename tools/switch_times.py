"""How long the window takes to show a scene: at its start, and after each switch.

    python3 tools/switch_times.py                      # demo_2d: s, s, s, Tab, shift+Tab, Tab
    python3 tools/switch_times.py --keys s,tab,tab     # other keys
    python3 tools/switch_times.py --scene pool_2d --size 1920x1080

Opens the real window (``python3 main.py SCENE``) on ``$DISPLAY``, or on an Xvfb server of
its own when there is none, presses the keys one by one with xdotool, and reads the
frames the window reports (its ``MRSPH_WINDOW_STATS`` lines, mrsph/app/hooks.py). For the
start and for each key it prints how long until the window answered (its first frame
that says it is loading, or the new scene itself) and until the first frame of the new
scene and solver that the simulation advanced ("first frame"); where a scene or solver
was opened before in this run, it says so ("seen"). The window builds what the next
key would open ahead while it waits (mrsph/app/ahead.py), so the times depend on
--settle; ``MRSPH_AHEAD=0`` in the environment times it without. ``s`` goes to the next pressure
solver of the scene schema's list, Tab to the next scene of ``python3 main.py list``,
shift+Tab to the one before. Each key waits for the window to be quiet (--settle
seconds of frames after the last switch) first.

``--levers`` measures, without a window, the three ways of opening the scenes of
``--sequence`` one after another (each way in a process of its own): all in one Taichi
program ("one program", what the window did before), ``ti.reset()`` before each build
("reset"), and each in a worker process with the used ones kept (``mrsph.app.host``,
"processes", what the window does). First each scene runs alone in a new process, twice
(the first compiles it, the second is "new process": what a scene seen on this machine
takes), in a kernel cache of its own (``--cache``: that one instead). A time is from the
request to the first frame advanced (the build, a step that compiles it, a reset, one
frame of 40 ms).

The times are wall-clock seconds on this machine, with the Taichi kernel cache as it
is: the first run after a change of the code compiles (tens of seconds), later runs
read the cache. docs/app.md records what this printed.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

DEFAULT_KEYS = "s,s,s,tab,shift+tab,tab"
DEFAULT_SEQUENCE = "demo_2d,demo_2d:pbf,demo_2d,demo_3d,demo_2d:pbf"
LEVERS = ("one program", "reset", "processes")
MARK = "switch_times: "  # the children's lines (Taichi prints its own beside them)
#: Seconds a switch may take before the tool gives up on it.
TIMEOUT_S = 240.0


def _free_display() -> int:
    for n in range(90, 200):
        if not Path(f"/tmp/.X{n}-lock").exists() and not Path(f"/tmp/.X11-unix/X{n}").exists():
            return n
    raise SystemExit("switch_times: no free X display number in :90-:199")


class Window:
    """``python3 main.py SCENE`` with the stats hook, and xdotool to press its keys."""

    def __init__(self, scene: str, size: tuple[int, int], display: str, tmp: Path, extra: list[str], cache=None):
        self.display, self.stats_path = display, tmp / "stats.jsonl"
        env = dict(os.environ, DISPLAY=display, MRSPH_WINDOW_STATS=str(self.stats_path))
        if cache:
            env["TI_OFFLINE_CACHE_FILE_PATH"] = str(Path(cache).resolve())
        self.log = open(tmp / "app.log", "w")
        self.started = time.time()
        cmd = [sys.executable, str(ROOT / "main.py"), scene, "--width", str(size[0]), "--height", str(size[1])]
        self.proc = subprocess.Popen(cmd + extra, cwd=tmp, env=env, stdout=self.log, stderr=subprocess.STDOUT)
        self.tmp = tmp
        self.wid = None

    def rows(self) -> list[dict]:
        if not self.stats_path.exists():
            return []
        lines = self.stats_path.read_text().splitlines()
        return [json.loads(line) for line in lines if line.strip().endswith("}")]

    def alive(self) -> None:
        if self.proc.poll() is not None:
            tail = (self.tmp / "app.log").read_text(errors="replace")[-2000:]
            raise SystemExit(f"switch_times: the window exited ({self.proc.returncode}):\n{tail}")

    def xdo(self, *args) -> str:
        env = dict(os.environ, DISPLAY=self.display)
        return subprocess.run(["xdotool", *args], capture_output=True, text=True, env=env, timeout=30).stdout

    def key(self, key: str) -> None:
        if self.wid is None:
            ids = self.xdo("search", "--name", "^mrsph - ").split()
            self.wid = ids[0] if ids else None
        if self.wid is not None:
            self.xdo("windowfocus", "--sync", self.wid)
        self.xdo("key", {"tab": "Tab", "shift+tab": "shift+Tab"}.get(key, key))

    def quit(self) -> None:
        self.xdo("key", "Escape")
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        self.log.close()


def _when(row: dict, seen_at: float) -> float:
    """The row's wall-clock time (its unix_s where the window writes one, else when the
    tool read it)."""
    return float(row.get("unix_s") or seen_at)


def wait_for(win: Window, start_rows: int, target, since: float) -> tuple[float | None, float | None, int]:
    """Wait for the first frame of ``target`` (scene, solver) that is not loading, in rows
    after ``start_rows``; returns (seconds to the window's first answer, seconds to that
    frame, its index)."""
    answered = None
    deadline = time.time() + TIMEOUT_S
    while time.time() < deadline:
        win.alive()
        now = time.time()
        rows = win.rows()
        for i, r in enumerate(rows[start_rows:], start_rows):
            mine = (r["scene"], r["solver"]) == target
            if answered is None and (r.get("loading") or mine):
                answered = _when(r, now) - since
            if mine and not r.get("loading"):
                return answered, _when(r, now) - since, i
        time.sleep(0.02)
    return answered, None, len(win.rows())


def settle(win: Window, seconds: float) -> None:
    """Let the window draw frames for ``seconds`` (the machine quiet before a key)."""
    end = time.time() + seconds
    while time.time() < end:
        win.alive()
        time.sleep(0.1)


def _make_sim(name, overrides=None):
    from mrsph import runtime
    from mrsph.scene.config import load_scene
    from mrsph.simulation import Simulation

    scene = load_scene(name)
    if overrides:
        scene = scene.with_overrides(overrides)
    return Simulation(scene, arch="cpu", threads=runtime.auto_threads(scene))


def _parse(item: str):
    name, _, solver = item.partition(":")
    return name, ({"fluid.solver": solver} if solver else None)


def lever_child(lever: str, sequence: list[str]) -> None:
    """One lever's times, one line per item: ``item seconds``."""
    from mrsph import runtime
    from mrsph.app.host import Sims, build

    if lever == "processes":
        sims = Sims(_make_sim, True)
        runtime.ensure("cpu")  # the window's own program, as the window has one
        running = None
    for item in sequence:
        name, overrides = _parse(item)
        t0 = time.perf_counter()
        if lever == "processes":
            sim = sims.open(name, overrides)
            while sim.poll() == "busy":
                time.sleep(0.005)
            sims.put_back(running)
            running = sim
        else:
            if lever == "reset":
                runtime.reset()
            sim = build(_make_sim, True, name, overrides)
        sim.advance_frame(0.04)
        sim.snapshot()
        print(f"{MARK}{item} {time.perf_counter() - t0:.2f}", flush=True)
    if lever == "processes":
        sims.put_back(running)
        sims.close()


def _run_child(lever: str, items: list[str], env) -> list[str]:
    proc = subprocess.run(
        [sys.executable, __file__, "--lever-child", lever, "--sequence", ",".join(items)],
        capture_output=True,
        text=True,
        env=env,
    )
    if proc.returncode != 0:
        raise SystemExit(f"switch_times: {lever}: {proc.stderr[-2000:]}")
    return [line[len(MARK) :].split()[-1] for line in proc.stdout.splitlines() if line.startswith(MARK)]


def levers(sequence: list[str], cache=None) -> int:
    """Each item once in a process of its own first (so that every scene and solver has
    run on this machine, and Taichi's cache holds it), then the sequence by each lever."""
    env = dict(os.environ)
    scratch = None
    if not cache:  # a cache of its own: no earlier run of the sequence in one program is in it
        scratch = cache = tempfile.mkdtemp(prefix="mrsph_levers_cache_")
    env["TI_OFFLINE_CACHE_FILE_PATH"] = str(Path(cache).resolve())
    fresh = {}
    for item in dict.fromkeys(sequence):
        fresh[item] = _run_child("one program", [item], env)[0]  # compiles it, cold
        fresh[item] = _run_child("one program", [item], env)[0]  # a new process, warm
    times = {lever: _run_child(lever, sequence, env) for lever in LEVERS}
    if scratch:
        shutil.rmtree(scratch, ignore_errors=True)
    seen = set()
    print(f"{'opens':22s} {'':18s} {'new process':>12s}" + "".join(f"{lv:>12s}" for lv in LEVERS))
    for i, item in enumerate(sequence):
        note = "seen in this run" if item in seen else "first in this run"
        seen.add(item)
        cells = "".join(f"{times[lv][i]:>12s}" for lv in LEVERS)
        print(f"{item.replace(':', ' '):22s} {note:18s} {fresh[item]:>12s}" + cells)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="demo_2d")
    ap.add_argument("--keys", default=DEFAULT_KEYS, help=f"comma-separated: s, tab, shift+tab (default {DEFAULT_KEYS})")
    ap.add_argument("--size", default="1280x720", help="window size WxH (default 1280x720)")
    ap.add_argument("--settle", type=float, default=3.0, help="seconds of frames before each key (default 3)")
    ap.add_argument(
        "--cache",
        metavar="DIR",
        help="Taichi's kernel cache for the window (TI_OFFLINE_CACHE_FILE_PATH; default: Taichi's own): a folder "
        "no other run cleans, on a machine where other runs fill the shared cache",
    )
    ap.add_argument("--levers", action="store_true", help="time the three ways of opening scenes, no window")
    ap.add_argument(
        "--sequence", default=DEFAULT_SEQUENCE, help=f"--levers: scenes[:solver] in turn (default {DEFAULT_SEQUENCE})"
    )
    ap.add_argument("--lever-child", help=argparse.SUPPRESS)
    ap.add_argument("args", nargs="*", help="more arguments for main.py (after --)")
    a = ap.parse_args(argv)
    sequence = [x.strip() for x in a.sequence.split(",") if x.strip()]
    if a.lever_child:
        lever_child(a.lever_child, sequence)
        return 0
    if a.levers:
        return levers(sequence, a.cache)
    for tool in ("xdotool",):
        if shutil.which(tool) is None:
            raise SystemExit(f"switch_times: {tool} is not installed")
    from mrsph.app.switch import solver_names
    from mrsph.scene.config import list_scenes, load_scene

    names = [n for n, _ in list_scenes()]
    solvers = solver_names()
    size = tuple(int(v) for v in a.size.lower().split("x"))
    xvfb = None
    display = os.environ.get("DISPLAY")
    if not display:
        if shutil.which("Xvfb") is None:
            raise SystemExit("switch_times: no DISPLAY and no Xvfb to start one")
        n = _free_display()
        xvfb = subprocess.Popen(
            ["Xvfb", f":{n}", "-screen", "0", f"{max(size[0], 1280)}x{max(size[1], 800)}x24", "-nolisten", "tcp"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        display = f":{n}"
        time.sleep(2.0)
    tmp = Path(tempfile.mkdtemp(prefix="mrsph_switch_"))
    scene = a.scene
    solver = str(load_scene(scene).get("fluid.solver"))
    seen = set()
    lines = []
    win = Window(scene, size, display, tmp, a.args, a.cache)
    try:
        answered, first, i = wait_for(win, 0, (scene, solver), win.started)
        seen.add((scene, solver))
        lines.append(("start", f"{scene} {solver}", answered, first, "first in this run"))
        for key in [k.strip().lower() for k in a.keys.split(",") if k.strip()]:
            settle(win, a.settle)
            if key == "s":
                target = (scene, solvers[(solvers.index(solver) + 1) % len(solvers)])
            elif key in ("tab", "shift+tab"):
                step = 1 if key == "tab" else -1
                nxt = names[(names.index(scene) + step) % len(names)]
                target = (nxt, str(load_scene(nxt).get("fluid.solver")))
            else:
                raise SystemExit(f"switch_times: unknown key {key!r} (expected s, tab or shift+tab)")
            start = len(win.rows())
            t0 = time.time()
            win.key(key)
            answered, first, i = wait_for(win, start, target, t0)
            note = "seen in this run" if target in seen else "first in this run"
            lines.append((key, f"{target[0]} {target[1]}", answered, first, note))
            seen.add(target)
            scene, solver = target
            if first is None:
                break
        win.quit()
    finally:
        if win.proc.poll() is None:
            win.proc.kill()
        if xvfb is not None:
            xvfb.terminate()
    print(f"{'key':10s} {'opens':24s} {'answered s':>10s} {'first frame s':>13s}  ")
    for key, what, answered, first, note in lines:
        ans = f"{answered:.2f}" if answered is not None else "-"
        fst = f"{first:.2f}" if first is not None else f"> {TIMEOUT_S:.0f}"
        print(f"{key:10s} {what:24s} {ans:>10s} {fst:>13s}  {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
