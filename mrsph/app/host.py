"""The window's simulations, each built in a process of its own and kept for a switch back.

Why. Taichi turns the kernels of every ``@ti.data_oriented`` object into IR again and
compiles them, unless its offline cache holds them under the same key, and a kernel's
key holds the ids of the fields it reads. A Simulation built in a fresh Taichi program
gets the ids a fresh process gives it and finds its kernels in the cache; a second
Simulation in the same program gets other ids and compiles everything again. Measured
(2026-12-01, warm cache, 2-core CPU, first frame after the build began): demo_2d 3.4 s
in a fresh process, 22-26 s as the second Simulation of a process. ``ti.reset()``
before the next build gives it a fresh program (3.1 s) but frees every field of the
window, whose GGUI window dies with it, and leaves nothing to keep for a switch back.
So the window builds each scene in a new process and keeps the last few it ran: a
switch back is a ``reset()`` there, a fraction of a second (docs/app.md).

How. Before the window initialises Taichi it forks a *zygote*: a copy of itself that
never initialises Taichi and waits. For each scene the zygote forks a *worker*: a
fresh process with Taichi imported, not initialised, and the window's ``make_sim`` in
its memory (a closure of the command line is fine: only requests, snapshots and errors
cross between the processes, pickled over a socket). The worker builds the simulation,
runs one step to compile it and resets it, then answers the window: a frame (the
mouse's disturbance in, an advance, the snapshot out), a reset, a parameter. While one
builds, the window goes on drawing, says how far it got, and quits at once on Esc.

Where fork is not to be had (not Linux), or Taichi is already running in this process
(a fork would copy its threads' state), or ``MRSPH_IN_PROCESS=1`` is set, the
simulations are built in the window's process (``LocalSim``), as one program: kept
ones still come back at once, new ones compile again.
"""

from __future__ import annotations

import collections
import contextlib
import ctypes
import io
import os
import pickle
import signal
import socket
import struct
import sys
import time
import traceback
import warnings
from multiprocessing.connection import Connection

from .ahead import Ahead

#: Simulations kept for a switch back besides the running one: a worker holds about
#: 320 MB for demo_3d, 180 MB for demo_2d.
KEEP = 3
#: Set to build every simulation in the window's own process.
IN_PROCESS_ENV = "MRSPH_IN_PROCESS"
#: What the loading panel says a simulation is doing, by stage.
STAGES = {
    "start": "starting a process for it",
    "build": "building the simulation",
    "compile": "compiling its first step",
    "reset": "restarting it",
}
#: Errors a worker passes on as they are; others it also prints with their traceback.
EXPECTED_ERRORS = ("SceneError", "SimulationError", "ValueError", "KeyError")
#: In-process builds: frames drawn before a build blocks the window (ImGui draws a new
#: panel from its second frame, so the message is seen before the wait).
LOCAL_FRAMES_BEFORE_BUILD = 2
_PR_SET_PDEATHSIG = 1


def separate_processes_possible() -> tuple[bool, str]:
    """(True, "") when simulations can be built in processes of their own, else why not."""
    if os.environ.get(IN_PROCESS_ENV):
        return False, f"{IN_PROCESS_ENV} is set"
    if not (sys.platform.startswith("linux") and hasattr(os, "fork") and hasattr(socket, "send_fds")):
        return False, "processes are forked on Linux only"
    try:
        from taichi.lang import impl

        if impl.get_runtime().prog is not None:
            return False, "Taichi is already initialised in this process"
    except (ImportError, AttributeError):
        pass
    return True, ""


def key_of(name: str, overrides: dict | None) -> tuple:
    """What identifies a simulation: the scene and the window's overrides."""
    return (str(name), tuple(sorted((overrides or {}).items())))


# ----------------------------------------------------------------------------- worker
def _die_with_parent(sig=signal.SIGTERM) -> None:
    """Linux: this process gets ``sig`` when its parent dies (no orphan compiles on)."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, int(sig))
    except (OSError, AttributeError):
        pass


def _portable(e: BaseException) -> BaseException:
    """``e`` if it survives pickling, else a RuntimeError with its type and message."""
    try:
        return pickle.loads(pickle.dumps(e))
    except Exception:
        return RuntimeError(f"{type(e).__name__}: {e}")


def _scene_out(scene):
    """The scene as it crosses to the window: itself where it pickles, else what makes
    it again (a Scene's typed parameters are classes made on the fly, which do not)."""
    try:
        pickle.dumps(scene)
        return scene
    except Exception:
        return (
            "scene",
            type(scene).__module__,
            type(scene).__qualname__,
            scene.name,
            scene.path,
            scene.data,
            scene._raw,
        )


def _scene_in(scene):
    """The scene as ``_scene_out`` sent it, made again (its parameters typed anew)."""
    if isinstance(scene, tuple) and scene and scene[0] == "scene":
        import importlib

        _, module, qualname, name, path, data, raw = scene
        return getattr(importlib.import_module(module), qualname)(name, path, data, raw)
    return scene


def _describe(sim) -> dict:
    """What the window reads of a simulation once, with its first snapshot."""
    live = getattr(sim, "LIVE_KEYS", None)
    return {
        "scene": _scene_out(sim.scene),
        "dim": int(sim.dim),
        "levels": int(sim.levels),
        "rest_density": getattr(sim, "rest_density", None),
        "live_keys": None if live is None else tuple(live),
        "snapshot": sim.snapshot(),
        "time": float(sim.time),
    }


def build(make_sim, takes_overrides: bool, name: str, overrides: dict | None, stage=lambda s: None):
    """``make_sim`` for ``name`` (with ``overrides`` where it takes them), then one step
    to compile it and a reset to t = 0: the window's first frame of it runs at once.
    ``stage(name)`` is told when the build moves on (STAGES)."""
    stage("build")
    sim = make_sim(name, dict(overrides)) if overrides and takes_overrides else make_sim(name)
    stage("compile")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # said again when the window runs it
        try:
            sim.step()
        except Exception:
            pass  # a step that fails fails again in the window, which says why
        sim.reset()
    return sim


def _frame(sim, disturbance, budget, advance: bool, seconds=None):
    sim.set_disturbance(disturbance)
    error = None
    if advance:
        try:
            sim.advance_frame(budget) if seconds is None else sim.advance_frame(budget, seconds)
        except Exception as e:  # the window stops and says why; the state is still shown
            error = _portable(e)
    try:
        snap = sim.snapshot()
    except Exception as e:
        snap, error = None, error or _portable(e)
    return ("frame", snap, float(sim.time), error)


def _finish() -> None:
    """End this process's Taichi program: Taichi writes the kernels it compiled into its
    offline cache only then (a worker killed before keeps nothing for the next run)."""
    try:
        from mrsph import runtime

        runtime.finish()
    except Exception:
        pass


def serve(conn: Connection, make_sim, takes_overrides: bool) -> None:
    """A worker's loop: build one simulation, then answer the window until it hangs up;
    then end its Taichi program (which writes the kernel cache)."""
    try:
        _serve(conn, make_sim, takes_overrides)
    finally:
        _finish()


def _serve(conn: Connection, make_sim, takes_overrides: bool) -> None:
    sim = None
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        op, args = msg[0], msg[1:]
        try:
            if op == "build":
                name, overrides, nice = args
                if nice:
                    os.nice(nice)  # before Taichi starts its threads: they inherit it
                # Taichi announces "Starting on arch=x64" on stdout in each process: the
                # window's own says it once, not once a worker
                with contextlib.redirect_stdout(io.StringIO()):
                    sim = build(make_sim, takes_overrides, name, overrides, stage=lambda s: conn.send(("stage", s)))
                reply = ("ready", _describe(sim))
            elif op == "reset":
                sim.set_disturbance(None)
                sim.reset()
                reply = ("ready", _describe(sim))
            elif op == "frame":
                reply = _frame(sim, *args)
            elif op == "set_param":
                sim.set_param(*args)
                reply = ("ok", _scene_out(getattr(sim, "scene", None)))
            else:
                reply = ("error", ValueError(f"unknown request {op!r}"))
        except Exception as e:
            if type(e).__name__ not in EXPECTED_ERRORS:
                traceback.print_exc()
            reply = ("error", _portable(e))
        try:
            conn.send(reply)
        except OSError:
            return


def _fork(child) -> tuple[int, socket.socket]:
    """Fork a process that runs ``child(its end of a new socket pair)`` and exits, with 1
    and its traceback printed if it raised; returns (its pid, this process's end)."""
    ours, its = socket.socketpair()
    sys.stdout.flush()  # what is still buffered would be written twice
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:
        code = 0
        try:
            ours.close()
            child(its)
        except BaseException:
            traceback.print_exc()
            code = 1
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
    its.close()
    return pid, ours


def _worker(sock: socket.socket, zygote_sock: socket.socket, make_sim, takes_overrides: bool) -> None:
    """A worker, just forked from the zygote: it serves one scene on ``sock``."""
    zygote_sock.close()
    signal.signal(signal.SIGCHLD, signal.SIG_DFL)
    _die_with_parent()
    serve(Connection(sock.detach()), make_sim, takes_overrides)


def _zygote(sock: socket.socket, make_sim, takes_overrides: bool) -> None:
    """The zygote's loop: a worker for every byte the window sends; its socket's other
    end goes back to the window. It outlives the window until its workers have ended
    (they write Taichi's kernel cache as they end), so it does not die with it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the window's; it ends the workers
    signal.signal(signal.SIGCHLD, signal.SIG_IGN)  # the kernel reaps the workers
    try:
        import mrsph.simulation  # noqa: F401  (the workers start with Taichi imported)
    except Exception:
        pass
    while True:
        try:
            request = sock.recv(1)
        except OSError:
            request = b""
        if not request:  # the window has gone: the workers end too, each writing its cache
            while True:
                try:
                    os.wait()
                except ChildProcessError:
                    return
                except InterruptedError:
                    continue
        pid, theirs = _fork(lambda mine: _worker(mine, sock, make_sim, takes_overrides))
        try:
            socket.send_fds(sock, [struct.pack("q", pid)], [theirs.fileno()])
        except OSError:
            return
        finally:
            theirs.close()


class Zygote:
    """The forked copy of this process that forks the workers (see the module's text)."""

    def __init__(self, make_sim, takes_overrides: bool):
        self.pid, self.sock = _fork(lambda its: _zygote(its, make_sim, takes_overrides))

    def spawn(self) -> tuple[int, Connection]:
        """A new worker: (its pid, the window's end of its socket)."""
        self.sock.sendall(b"w")
        msg, fds, _, _ = socket.recv_fds(self.sock, 8, 1)
        if not fds or len(msg) != 8:
            raise OSError("the simulations' zygote process did not answer")
        return struct.unpack("q", msg)[0], Connection(fds[0])

    def close(self) -> None:
        """Hang up: the zygote ends once its workers have (it is not waited for: one
        still writing its cache must not hold the window open)."""
        self.sock.close()
        try:
            os.waitpid(self.pid, os.WNOHANG)
        except ChildProcessError:
            pass


# ----------------------------------------------------------------------------- window side
class RemoteSim:
    """A simulation in a worker, with the part of the Simulation API the window uses.

    ``poll()`` follows a build or a reset without waiting ("busy", "ready" or "failed",
    with ``stage`` and ``error``); once ready, ``advance_frame``, ``snapshot``,
    ``set_disturbance``, ``set_param`` and ``reset`` act in the worker, and ``scene``,
    ``dim``, ``levels``, ``rest_density``, ``LIVE_KEYS`` and ``time`` are its."""

    def __init__(self, pid: int, conn: Connection, key: tuple):
        self.pid, self.conn, self.key = pid, conn, key
        self.state, self.stage, self.error = "busy", "start", None
        self.since = time.perf_counter()
        self.scene = self.dim = self.levels = self.rest_density = None
        self.live_keys = None
        self.time = 0.0
        self._snap = None
        self._disturbance = None

    # -- lifecycle -----------------------------------------------------------------------
    def begin(self, op: str, *args) -> None:
        """Start a build or a reset; ``poll`` says when it is done."""
        self.state, self.error, self.since = "busy", None, time.perf_counter()
        self.stage = "start" if op == "build" else op
        try:
            self.conn.send((op, *args))
        except OSError:
            self._stopped()

    def poll(self) -> str:
        while self.state == "busy":
            try:
                if not self.conn.poll(0):
                    break
                msg = self.conn.recv()
            except (EOFError, OSError):
                self._stopped()
                break
            if msg[0] == "stage":
                self.stage = msg[1]
            elif msg[0] == "ready":
                self._adopt(msg[1])
                self.state = "ready"
            elif msg[0] == "error":
                self.state, self.error = "failed", msg[1]
        return self.state

    def alive(self) -> bool:
        return self.state != "dead"

    def hurry(self) -> None:
        """Back to the window's priority, every thread of the worker, where this process
        may raise a priority (root, or RLIMIT_NICE); else it stays as it was built."""
        try:
            tids = [int(t) for t in os.listdir(f"/proc/{self.pid}/task")]
        except (OSError, ValueError):
            tids = [self.pid]
        ours = os.getpriority(os.PRIO_PROCESS, 0)
        for tid in tids:
            try:
                os.setpriority(os.PRIO_PROCESS, tid, ours)
            except OSError:
                pass

    def close(self) -> None:
        """Let the worker go: one that runs ends its program, writing the kernels it
        compiled into Taichi's cache; one still building is ended at once (a newer
        choice replaced it, or the window closes)."""
        if self.state == "busy":
            try:
                os.kill(self.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
        else:
            try:
                self.conn.send(None)
            except OSError:
                pass
        try:
            self.conn.close()
        except OSError:
            pass
        self.state = "dead"

    def _stopped(self) -> None:
        self.state = "dead"
        self.error = RuntimeError("the simulation's process stopped")

    def _adopt(self, info: dict) -> None:
        self.scene, self.dim, self.levels = _scene_in(info["scene"]), info["dim"], info["levels"]
        self.rest_density, self.live_keys = info["rest_density"], info["live_keys"]
        self._snap, self.time = info["snapshot"], info["time"]

    def _ask(self, *msg):
        """Send a request and wait for its answer; the worker's error is raised here."""
        if self.state == "dead":
            raise self.error
        try:
            self.conn.send(msg)
            reply = self.conn.recv()
        except (EOFError, OSError):
            self._stopped()
            raise self.error from None
        if reply[0] == "error":
            raise reply[1]
        return reply

    # -- the Simulation API --------------------------------------------------------------
    @property
    def LIVE_KEYS(self):  # noqa: N802  (the Simulation's name)
        return self.live_keys

    def set_disturbance(self, d) -> None:
        self._disturbance = d  # goes with the next frame's request

    def advance_frame(self, wall_budget: float | None = None, seconds: float | None = None) -> None:
        _, snap, t, error = self._ask("frame", self._disturbance, wall_budget, True, seconds)
        self._snap, self.time = snap if snap is not None else self._snap, t
        if error is not None:
            raise error

    def snapshot(self):
        if self._snap is None:
            _, self._snap, self.time, _ = self._ask("frame", self._disturbance, None, False)
        return self._snap

    def reset(self) -> None:
        self._adopt(self._ask("reset")[1])

    def set_param(self, key: str, value) -> None:
        scene = self._ask("set_param", key, value)[1]
        if scene is not None:
            self.scene = _scene_in(scene)


class LocalSim:
    """A simulation built in the window's own process, polled like a RemoteSim: a few
    frames say what is coming, then a build blocks the window, then the compile."""

    def __init__(self, make_sim, takes_overrides: bool, name: str, overrides: dict | None, key: tuple):
        self.make, self.takes, self.name, self.overrides, self.key = make_sim, takes_overrides, name, overrides, key
        self.sim = None
        self.state, self.stage, self.error = "busy", "build", None
        self.since = time.perf_counter()
        self._polls = 0

    def begin(self, op: str, *args) -> None:
        self.state, self.error, self.since, self._polls = "busy", None, time.perf_counter(), 0
        self.stage = "reset" if op == "reset" else "build"

    def poll(self) -> str:
        if self.state != "busy":
            return self.state
        self._polls += 1
        if self._polls <= LOCAL_FRAMES_BEFORE_BUILD:
            return self.state
        try:
            if self.stage == "reset":
                self.sim.set_disturbance(None)
                self.sim.reset()
            else:
                self.sim = build(self.make, self.takes, self.name, self.overrides)
            self.state = "ready"
        except Exception as e:
            self.state, self.error = "failed", e
        return self.state

    def alive(self) -> bool:
        return self.state != "dead"

    def hurry(self) -> None:
        pass

    def close(self) -> None:
        self.sim, self.state = None, "dead"

    @property
    def LIVE_KEYS(self):  # noqa: N802  (the Simulation's name)
        return getattr(self.sim, "LIVE_KEYS", None)

    def __getattr__(self, name):
        if name == "sim":  # not set yet: no recursion through __getattr__
            raise AttributeError(name)
        sim = self.__dict__.get("sim")
        if sim is None:
            raise AttributeError(f"{name}: the simulation is not built yet")
        return getattr(sim, name)


class Sims:
    """The window's simulations: the one being opened, up to ``keep`` it ran before
    (least recently used first out), and those built ahead of a switch (``ahead``), in
    processes of their own where possible."""

    def __init__(self, make_sim, takes_overrides: bool, keep: int = KEEP):
        self.make, self.takes, self.keep_n = make_sim, takes_overrides, keep
        self.kept: collections.OrderedDict = collections.OrderedDict()
        self.zygote = None
        self.ahead = Ahead(self, key_of)
        ok, self.why_local = separate_processes_possible()
        if ok:
            try:
                self.zygote = Zygote(make_sim, takes_overrides)
            except OSError as e:
                self.why_local = f"cannot fork ({e})"

    @property
    def separate(self) -> bool:
        """Whether simulations run in processes of their own."""
        return self.zygote is not None

    def open(self, name: str, overrides: dict | None = None):
        """A simulation of ``name`` with ``overrides``, busy until ``poll()`` says ready:
        one built ahead comes as it is, a kept one restarts, else a new one is built."""
        key = key_of(name, overrides)
        handle = self.ahead.take(key)
        if handle is not None:
            return handle
        handle = self.kept.pop(key, None)
        if handle is not None and handle.alive():
            handle.begin("reset")
            return handle
        handle = self.spawn(name, overrides)
        return handle if handle is not None else LocalSim(self.make, self.takes, name, overrides, key)

    def spawn(self, name: str, overrides: dict | None, nice: int = 0):
        """A new worker building ``name`` (at ``nice``), or None where none can be forked."""
        if self.zygote is None:
            return None
        try:
            pid, conn = self.zygote.spawn()
        except OSError:
            self.zygote = None
            self.why_local = "the zygote process stopped"
            return None
        handle = RemoteSim(pid, conn, key_of(name, overrides))
        handle.begin("build", name, overrides, nice)
        return handle

    def put_back(self, handle) -> None:
        """The window leaves ``handle``: kept for a switch back if it runs, else closed."""
        if handle is None:
            return
        if handle.state != "ready":
            handle.close()
            return
        old = self.kept.pop(handle.key, None)
        if old is not None and old is not handle:
            old.close()
        self.kept[handle.key] = handle
        while len(self.kept) > self.keep_n:
            self.kept.popitem(last=False)[1].close()

    def close(self) -> None:
        self.ahead.close()
        for handle in self.kept.values():
            handle.close()
        self.kept.clear()
        if self.zygote is not None:
            self.zygote.close()
            self.zygote = None
