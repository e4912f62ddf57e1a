"""The command line, run as ``python3 main.py`` in a subprocess.

Scene and usage errors must end with exit status 2 and readable lines (file, key, what
was expected), never a traceback; a tiny headless run must write the documented dumps.
Only three runs build a simulation (one Taichi compile, then the offline cache); the
rest stop before Taichi is imported.
"""

import csv
import os
import re
import subprocess
import sys
from pathlib import Path

import meshio
import numpy as np
import pytest

from mrsph.cli.commands import NO_END, _show_warning
from mrsph.io.output import read_ply, stats_columns
from mrsph.scene.config import list_scenes

REPO = Path(__file__).resolve().parent.parent
TIMEOUT_S = 300

TINY = """\
description = "tiny 2D dam break for the CLI tests"
dim = 2

[domain]
min = [0.0, 0.0]
max = [1.0, 0.6]

[particles]
spacing = 0.005

[fluid]
viscosity = 1.0
stiffness = 1000.0

[[fluid.blocks]]
min = [0.0, 0.0]
max = [0.25, 0.5]
"""
# 16 x 33 = 528 particles: enough to be a fluid, fast to run
TINY_SPACING = "particles.spacing=0.015"
FRAMES = 3


def run(*args, cwd=REPO):
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["MRSPH_NO_VULKAN"] = "1"  # never probe GGUI from these tests
    return subprocess.run(
        [sys.executable, str(REPO / "main.py"), *map(str, args)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )


def scene_file(tmp_path, extra: str = "", name: str = "tiny.toml") -> Path:
    """TINY plus ``extra``; lines of ``extra`` starting with "particles." go into
    TINY's [particles] table."""
    inside = "".join(ln[len("particles.") :] + "\n" for ln in extra.splitlines() if ln.startswith("particles."))
    after = "".join(ln + "\n" for ln in extra.splitlines() if not ln.startswith("particles."))
    path = tmp_path / name
    path.write_text(TINY.replace("[fluid]\n", inside + "\n[fluid]\n") + after, encoding="utf-8")
    return path


def assert_usage_error(proc, *needles):
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr
    lines = proc.stderr.strip().splitlines()
    for needle in needles:
        assert any(needle in line for line in lines), f"{needle!r} not in:\n{proc.stderr}"


# ----------------------------------------------------------------------- scene errors
SCENE_ERRORS = {
    "unknown key": ('[run]\nfram = 3\n', [], ["run.fram: unknown key (did you mean 'frames'?)"]),
    "bad type": ('[physics]\ncfl = "fast"\n', [], ['physics.cfl: wrong type (got "fast" (string)']),
    "out of range": (
        '[render]\nwidth = 10\n',
        [],
        ["render.width: out of range (got 10; expected an integer in [64, 8192])"],
    ),
    "block outside domain": (
        '[[fluid.blocks]]\nmin = [0.5, 0.5]\nmax = [2.0, 0.9]\n',
        [],
        ["fluid.blocks.1: outside the domain"],
    ),
    "block inside obstacle": (
        '[[obstacles]]\nshape = "sphere"\ncenter = [0.1, 0.1]\nradius = 0.05\n',
        [],
        ["fluid.blocks.0: overlaps obstacles.0"],
    ),
    "capacity too small": (
        "particles.capacity = 10",
        [],
        ["particles.capacity: too small for the fluid blocks (got 10; expected >= 5000"],
    ),
    "block thinner than the spacing": (
        '[[fluid.blocks]]\nmin = [0.5, 0.0]\nmax = [0.503, 0.3]\n',
        [],
        ["fluid.blocks.1: holds no particle", "(not on axis x)"],
    ),
    "block thinner than the spacing on two axes": (
        '[[fluid.blocks]]\nmin = [0.5, 0.0]\nmax = [0.503, 0.003]\n',
        [],
        ["fluid.blocks.1: holds no particle", "(not on axes x, y)"],
    ),
    "bad --set syntax": ("", ["--set", "fluid.viscosity"], ["--set fluid.viscosity: not KEY=VALUE"]),
    "unknown --set key": (
        "",
        ["--set", "fluid.viscosty=2"],
        ["--set fluid.viscosty: unknown key (did you mean 'viscosity'?)"],
    ),
}


@pytest.mark.parametrize("case", SCENE_ERRORS, ids=lambda c: c.replace(" ", "-"))
def test_scene_error_exits_2_with_file_and_key(tmp_path, case):
    extra, args, needles = SCENE_ERRORS[case]
    path = scene_file(tmp_path, extra)
    proc = run(path, "--headless", "--frames", 1, *args, cwd=tmp_path)
    label = "--set" if case.endswith("--set key") or "syntax" in case else "tiny.toml"
    assert_usage_error(proc, *needles, label)


def test_every_problem_is_reported_at_once(tmp_path):
    path = scene_file(tmp_path, '[run]\nfram = 3\n[physics]\ncfl = "fast"\n')
    proc = run(path, "--headless", "--set", "fluid.viscosty=2", cwd=tmp_path)
    assert_usage_error(proc, "run.fram: unknown key", "physics.cfl: wrong type", "--set fluid.viscosty: unknown key")
    assert len(proc.stderr.strip().splitlines()) == 3


def test_missing_scene_name():
    proc = run("no_such_scene", "--headless", "--frames", 1)
    assert_usage_error(proc, "no_such_scene: no such scene or file")
    for name, _ in list_scenes():
        assert name in proc.stderr


def test_invalid_toml(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text("dim = = 2\n", encoding="utf-8")
    assert_usage_error(run(path, "--headless", cwd=tmp_path), "broken.toml: invalid TOML")


def test_headless_without_an_end_is_refused(tmp_path):
    path = scene_file(tmp_path)  # run.frames defaults to 0
    proc = run(path, "--headless", cwd=tmp_path)
    assert_usage_error(proc, NO_END)
    assert proc.stderr.strip() == NO_END
    assert "--frames N" in NO_END and "run.frames" in NO_END
    assert_usage_error(run(path, "--out", tmp_path / "x.mp4", cwd=tmp_path), NO_END)


def test_a_recording_over_an_earlier_file_says_it_replaces_it(tmp_path):
    path, gif = scene_file(tmp_path), tmp_path / "x.gif"
    first = run(path, "--frames", 1, "--out", gif, "--quiet", "--width", 64, "--height", 64, cwd=tmp_path)
    assert first.returncode == 0 and gif.is_file() and "replaced" not in first.stderr, first.stderr
    again = run(path, "--frames", 1, "--out", gif, "--quiet", "--width", 64, "--height", 64, cwd=tmp_path)
    assert again.returncode == 0 and f"mrsph: {gif} exists; it is replaced" in again.stderr, again.stderr


def test_bad_option_values(tmp_path):
    path = scene_file(tmp_path)
    assert_usage_error(run(path, "--headless", "--frames", 0), "--frames")
    assert_usage_error(run(path, "--arch", "tpu"), "--arch")
    assert_usage_error(run(path, "--dump-format", "csv"), "--dump-format")
    assert_usage_error(run(path, "--frame-budget", "-5"), "--frame-budget", "milliseconds >= 0")
    assert_usage_error(run(path, "--frame-budget", "inf"), "--frame-budget", "finite")
    for fps in ("inf", "0.001", "nan"):  # inf and 1e-3 used to end in encoder tracebacks
        assert_usage_error(run(path, "--frames", 2, "--fps", fps, "--out", tmp_path / "x.gif"), "--fps", "[0.1, 1000]")
    assert_usage_error(run(path, "--frames", 2, "--out", tmp_path / "x.avi"), "--out", ".mp4")
    assert_usage_error(
        run(path, "--frames", 2, "--out", tmp_path / "x.gif", "--width", 100000), "--width", "[64, 8192]"
    )
    # argparse's own errors in one line too, not after its usage block
    for args in (("--bogus",), ("--frames", "abc"), ("--arch", "tpu")):
        proc = run(path, *args)
        assert_usage_error(proc, "error: ")
        assert len(proc.stderr.strip().splitlines()) == 1, f"{args}: {proc.stderr}"


def test_unwritable_outputs_are_refused_before_anything_runs(tmp_path):
    """--out and --dump are checked before the simulation is built: one line naming
    the option and the path, exit status 2."""
    path = scene_file(tmp_path)
    a_file = tmp_path / "a_file"
    a_file.write_text("not a directory", encoding="utf-8")
    cases = [
        (("--headless", "--frames", 1, "--dump", a_file), "--dump", "not a directory"),
        (("--frames", 1, "--out", a_file / "x.gif"), "--out", "not a directory"),
        (("--frames", 1, "--out", a_file / "frames"), "--out", "cannot make the directory"),
        # found only once the run was made, by an encoder that wrote its log after it
        (("--frames", 1, "--out", "same.mp4", "--dump", "same.mp4"), "--dump", "the path of --out"),
        (("--frames", 1, "--out", "v.gif", "--dump", "v.gif/dumps"), "--dump", "inside --out v.gif, the file"),
    ]
    for args, flag, why in cases:
        proc = run(path, *args, cwd=tmp_path)
        assert_usage_error(proc, f"error: {flag} ", why)
        assert len(proc.stderr.strip().splitlines()) == 1, f"{args}: {proc.stderr}"
        assert "Starting on arch" not in proc.stdout + proc.stderr, f"{args}: Taichi was started"


def test_an_encoder_that_stops_mid_run_is_one_line():
    """imageio's error for a video encoder that stopped carries the encoder's whole command
    line over several lines; the run reports it in one, after the encoder's own reason."""
    from mrsph.cli.commands import _os_error_line

    log = "[Errno 32] Broken pipe\n\nFFMPEG COMMAND:\n/usr/bin/ffmpeg -y -f rawvideo x.mp4\n\nFFMPEG STDERR OUTPUT:\n"
    line = _os_error_line(OSError(log))
    assert line == "the video encoder (ffmpeg) stopped ([Errno 32] Broken pipe); its own message is above"
    assert _os_error_line(OSError(28, "No space left on device")) == "[Errno 28] No space left on device"


def test_a_set_that_breaks_another_key_is_named(tmp_path):
    """A --set whose value is fine but leaves another key wrong (a spacing wider than a
    fluid block) is named next to the scene file."""
    proc = run(scene_file(tmp_path), "--headless", "--frames", 1, "--set", "particles.spacing=0.3", cwd=tmp_path)
    assert_usage_error(proc, "tiny.toml with --set particles.spacing: fluid.blocks.0: holds no particle")


def test_a_headless_run_says_the_recording_options_do_nothing_there(tmp_path):
    """--width, --height and --fps shape a recording; a headless run without --out renders
    nothing, and says so rather than take them in silence."""
    proc = run(scene_file(tmp_path), "--headless", "--frames", 1, "--width", 320, "--fps", 60, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "mrsph: --width, --fps apply to recordings (--out); a headless run renders nothing" in proc.stderr
    assert "nothing written (--dump DIR keeps the frames, --out FILE a video)" in proc.stdout, proc.stdout


def test_frame_budget_is_read_in_milliseconds_and_zero_means_whole_frames():
    from mrsph.cli.commands import build_parser

    parse = build_parser().parse_args
    budgets = {args: parse(list(args)).frame_budget for args in [(), ("--frame-budget", "25"), ("--frame-budget", "0")]}
    assert budgets == {(): 0.04, ("--frame-budget", "25"): 0.025, ("--frame-budget", "0"): None}, budgets


# ------------------------------------------------------------------------ help, list
def test_help_lists_every_option_and_its_default():
    proc = run("--help")
    assert proc.returncode == 0, proc.stderr
    out = " ".join(proc.stdout.split())  # undo argparse's line wrapping
    options = [
        "--arch",
        "--threads",
        "--version",
        "--headless",
        "--frames",
        "--out",
        "--width",
        "--height",
        "--fps",
        "--frame-budget",
        "--set",
        "--dump",
        "--dump-format",
        "--quiet",
        "SCENE",
    ]
    for option in options:
        assert option in out, option
    for default in [
        "(default: auto)",
        "under 12k particles",
        "(default: off)",
        "(default: the scene's run.frames",
        "(default: no recording)",
        "(default: the scene's render.width",
        "(default: the scene's render.height",
        "(default: the scene's run.fps)",
        "(default: 40)",
        "(default: none)",
        "(default: no dump)",
        "(default: npz)",
        "(default: dam_break_2d)" if not (REPO / "scenes/demo_2d.toml").exists() else "(default: demo_2d)",
    ]:
        assert default in out, default
    assert out.count("(default:") >= len(options) - 2  # --help and --version have none
    assert "python3 main.py list" in out and "python3 main.py bench" in out and "python3 main.py keys" in out
    assert "the window's keys and mouse:" in out and "next / previous scene" in out


def test_version_and_help_as_a_command():
    """--version names the package's version; "help" reads as --help, "help bench" as
    bench --help."""
    import tomllib

    version = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]
    proc = run("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"mrsph {version}", proc.stdout + proc.stderr
    proc = run("help")
    assert proc.returncode == 0 and proc.stdout.startswith("usage: python3 main.py [-h]"), proc.stdout + proc.stderr
    proc = run("help", "bench")
    assert proc.returncode == 0 and proc.stdout.startswith("usage: python3 main.py bench"), proc.stdout + proc.stderr
    assert "``" not in proc.stdout, "the bench's help shows the docstring's markup"


def test_a_directory_for_a_scene_is_named_as_one(tmp_path):
    assert_usage_error(run(tmp_path, "--headless", "--frames", 1), f"{tmp_path}: a directory (expected a scene name")


def test_list_takes_no_arguments_and_commands_come_first():
    proc = run("list", "extra")
    assert proc.returncode == 2 and proc.stderr.strip() == (
        "python3 main.py list: error: unrecognized arguments: extra (list takes none)"
    ), proc.stderr
    for command in ("list", "keys", "bench"):
        proc = run("--quiet", command)
        assert proc.returncode == 2 and proc.stderr.strip() == (
            f"python3 main.py: error: '{command}' is a command: it comes first "
            f"(python3 main.py {command} ...), before any option"
        ), proc.stderr


def _readme_keys_table() -> str:
    """The first table of the README's "Controls (window)" section."""
    section = (REPO / "README.md").read_text(encoding="utf-8").split("## Controls (window)\n", 1)[1]
    lines = section.strip().splitlines()
    return "\n".join(lines[: next((i for i, line in enumerate(lines) if not line.startswith("|")), len(lines))])


def test_the_window_keys_come_from_one_table():
    """The README's table, ``python3 main.py keys`` and ``--help`` all come from
    mrsph/app/keys.py (the help panel draws the same text: mrsph.app.hud.help_rows)."""
    from mrsph.app.keys import KEYS, markdown_table, plain, text_table

    assert _readme_keys_table() == markdown_table(), (
        "README.md's Controls table is not mrsph/app/keys.py's: python3 main.py keys --markdown prints it"
    )
    table = text_table()
    flat = " ".join(table.split())
    for k in KEYS:  # every row is in the text, its action's words in order
        words = plain(k.action).split()
        assert " ".join(words[:2]) in flat, k
    keys, help_ = run("keys"), run("--help")
    assert keys.returncode == 0 and help_.returncode == 0, keys.stderr + help_.stderr
    assert keys.stdout.strip("\n") == table, keys.stdout
    assert table in help_.stdout, help_.stdout[-2000:]
    assert run("keys", "--markdown").stdout.strip() == markdown_table()
    proc = run("keys", "extra")
    assert proc.returncode == 2 and "keys takes only --markdown" in proc.stderr, proc.stderr


def test_list_shows_every_scene_with_its_description():
    proc = run("list")
    assert proc.returncode == 0, proc.stderr
    scenes = list_scenes()
    assert scenes, "no scenes in scenes/"
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == len(scenes)
    for line, (name, description) in zip(lines, scenes):
        assert line.split()[0] == name
        assert line.endswith(description) and description


def test_runtime_warnings_print_as_one_line(capsys):
    show = _show_warning(lambda *a: pytest.fail("a RuntimeWarning went to the default handler"))
    show(RuntimeWarning("particle pool full"), RuntimeWarning, "solver.py", 12)
    assert capsys.readouterr().err == "warning: particle pool full\n"


# ----------------------------------------------------------------------------- dumps
def test_headless_dump_npz(tmp_path):
    path = scene_file(tmp_path)
    out = tmp_path / "dump"
    proc = run(
        path, "--headless", "--frames", FRAMES, "--set", TINY_SPACING, "--dump", out, "--arch", "cpu", cwd=tmp_path
    )
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert f"{FRAMES} frames" in proc.stdout and "total mass" in proc.stdout

    files = sorted(p.name for p in out.glob("frame_*"))
    assert files == [f"frame_{i:05d}.npz" for i in range(FRAMES + 1)]
    n = None
    for name in files:
        with np.load(out / name) as f:
            assert sorted(f.files) == ["kind", "level", "m", "p", "rho", "v", "x"]
            n = len(f["m"])
            assert f["x"].shape == (n, 2) and f["v"].shape == (n, 2)
            assert f["level"].dtype == np.int32 and f["kind"].dtype == np.int32
            assert np.isfinite(f["x"]).all()
    assert n == 16 * 33

    with open(out / "stats.csv", newline="") as f:
        rows = list(csv.reader(f))
    header = rows[0]
    assert header[: len(stats_columns(2, 1))] == stats_columns(2, 1)
    for extra in ["n_virtual_level_0", "n_transient", "splits", "merges", "absorbed", "refused"]:
        assert extra in header
    body = [dict(zip(header, r)) for r in rows[1:]]
    assert [int(r["frame"]) for r in body] == list(range(FRAMES + 1))
    assert len({r["total_mass"] for r in body}) == 1  # exactly constant
    assert float(body[-1]["time"]) == pytest.approx(FRAMES / 30.0)


def test_a_shorter_dump_leaves_no_frames_of_the_longer_one(tmp_path):
    """Dumping 1 frame where 3 were dumped (and a user's file sits beside them): the
    folder holds this run's 2 frames and the user's file, and the removal is reported
    in one line. Stale frames used to stay, read by ParaView as part of the series."""
    path = scene_file(tmp_path)
    out = tmp_path / "dump"
    first = run(
        path, "--headless", "--frames", 3, "--set", TINY_SPACING, "--dump", out, "--dump-format", "vtk", cwd=tmp_path
    )
    assert first.returncode == 0, first.stderr
    (out / "notes.txt").write_text("mine")
    proc = run(path, "--headless", "--frames", 1, "--set", TINY_SPACING, "--dump", out, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in out.iterdir()) == ["frame_00000.npz", "frame_00001.npz", "notes.txt", "stats.csv"]
    said = [line for line in proc.stderr.splitlines() if "removed" in line]
    assert said == [f"warning: {out}: removed 4 frame file(s) of an earlier run"], proc.stderr


@pytest.mark.parametrize("fmt", ["ply", "vtk"])
def test_headless_dump_ply_and_vtk(tmp_path, fmt):
    path = scene_file(tmp_path)
    out = tmp_path / "dump"
    proc = run(
        path,
        "--headless",
        "--frames",
        1,
        "--set",
        TINY_SPACING,
        "--dump",
        out,
        "--dump-format",
        fmt,
        "--arch",
        "cpu",
        "--quiet",
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    suffix = "ply" if fmt == "ply" else "vtu"
    files = sorted(out.glob(f"frame_*.{suffix}"))
    assert [p.name for p in files] == [f"frame_{i:05d}.{suffix}" for i in range(2)]
    for p in files:
        if fmt == "ply":
            cols = read_ply(p)
            assert len(cols["x"]) == 16 * 33 and np.all(cols["z"] == 0)
        else:
            mesh = meshio.read(p)
            assert mesh.points.shape == (16 * 33, 3)
            assert set(mesh.point_data) == {"v", "m", "rho", "p", "level", "kind"}
    assert (out / "stats.csv").is_file()


def test_simulation_error_exits_1(tmp_path):
    """A time step below dt_min on the first step: one 'error:' line, exit status 1, that
    names the bound which set it (at rest, the sound speed)."""
    path = scene_file(tmp_path)
    proc = run(
        path,
        "--headless",
        "--frames",
        1,
        "--set",
        TINY_SPACING,
        "--set",
        "physics.dt_min=0.0019",
        "--arch",
        "cpu",
        "--quiet",
        cwd=tmp_path,
    )
    assert proc.returncode == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and "dt_min" in errors[0], proc.stderr
    assert "the sound speed sqrt(fluid.stiffness) = 31.6 m/s" in errors[0], errors[0]


def _imported_modules(path: Path) -> set[str]:
    """Every module ``path`` imports, at the top or inside a function, as absolute names."""
    import ast

    package = ".".join(path.relative_to(REPO).with_suffix("").parts[:-1])
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package.rsplit(".", node.level - 1)[0] if node.level else ""
            mod = ".".join(p for p in (base, node.module) if p)
            names.add(mod)
            names.update(f"{mod}.{a.name}" for a in node.names)  # from . import bench
    return names


def test_command_line_helpers_form_no_import_circle():
    """cli -> bench -> options and app -> options: bench and the app never import cli,
    and options, the bottom floor, imports neither cli nor bench."""
    floor = {"mrsph.cli.commands", "mrsph.cli.bench"}
    for path in [REPO / "mrsph" / "cli" / "bench" / "__init__.py", *sorted((REPO / "mrsph" / "app").glob("*.py"))]:
        assert "mrsph.cli.commands" not in _imported_modules(path), f"{path.name} imports mrsph.cli.commands"
    assert not floor & _imported_modules(REPO / "mrsph" / "cli" / "options.py")
    code = (
        "import sys, mrsph.cli.options; "
        "print(sorted({'mrsph.cli.commands', 'mrsph.cli.bench', 'taichi'} & set(sys.modules)))"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert proc.returncode == 0 and proc.stdout.strip() == "[]", proc.stdout + proc.stderr


def test_readme_is_short_and_its_links_lead_somewhere():
    """The README stays at most 12 KB, and every file it links to exists."""
    text = (REPO / "README.md").read_text(encoding="utf-8")
    assert len(text.encode()) <= 12 * 1024, f"README.md is {len(text.encode())} bytes (expected <= 12 KB)"
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    missing = [t for t in links if not t.startswith("http") and not (REPO / t).exists()]
    assert links and not missing, f"README.md links to missing files: {missing}"
