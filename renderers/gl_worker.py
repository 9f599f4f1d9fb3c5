r'''OpenGL (OSMesa) in a child process, for the osmesa and osmesa_terrain renderers

SYNOPSIS

    from renderers.gl_worker import call

    version = call("osmesa.version")                    # starts the worker on first use
    img = call("osmesa.render_pinhole", pinhole, pattern, Rt_cam_board, K, tile)
    r = call("terrain.render", model, terrain, Rt_ref_terrain, spp=2)   # a TerrainRender

The renderers' OpenGL calls run in one worker process per process that uses
them (`python -m renderers.gl_worker`, started on first use, restarted in a
forked child and after it dies); the caller never loads libOSMesa. Why: Mesa's
llvmpipe links its own LLVM (libLLVM-15), numba's llvmlite another, and two LLVMs
in one process were once the suspect of a heap-corruption abort at interpreter
exit. That abort was found elsewhere (pupil_apriltags' detector freed after its tag
family: targets.detect_apriltag._destroy); the worker stays because it keeps a
second LLVM and Mesa's threads out of every campaign worker and test process.

A request is a pickled (name, args, kwargs) on the worker's stdin; the reply,
a pickled ("ok", value) or ("error", exception), comes back on its stdout (the
worker points its own fd 1 at stderr, so nothing a library prints can reach
the channel). An exception raised in the worker is raised again in the caller,
same class and message. A worker that dies is a RendererError with its exit
status; the next call starts a new one. Calls are serialised (one lock), as
OpenGL calls were in-process.
'''

import atexit
import os
import pickle
import subprocess
import sys
import threading
from pathlib import Path

from .base import RendererError

ROOT = Path(__file__).resolve().parent.parent
_LOCK = threading.Lock()
_WORKER = []          # [Worker] of this process
_INHERITED = []       # workers a fork inherited: kept referenced, never used


def _functions():
    r'''{name: callable} the worker serves (imported in the worker only)'''
    from renderers import osmesa, osmesa_terrain

    state = {}

    def rasteriser():
        if "r" not in state:
            state["r"] = osmesa.GLRasteriser()
        return state["r"]

    return {
        "osmesa.version": lambda: rasteriser().version(),
        "osmesa.render_pinhole": lambda *a, **k: rasteriser().render_pinhole(*a, **k),
        "terrain.version": osmesa_terrain.gl_version_here,
        "terrain.render": osmesa_terrain.render_terrain_here,
        "terrain.cell_shadows": osmesa_terrain.cell_shadows_here,
        "pid": os.getpid,
    }


class Worker:
    r'''One worker process and its two pipes'''

    def __init__(self):
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(
            [str(ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
        self.owner = os.getpid()
        self.proc = subprocess.Popen([sys.executable, "-m", "renderers.gl_worker"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     env=env, cwd=str(ROOT))

    def alive(self):
        return self.proc.poll() is None

    def call(self, name, args, kwargs):
        try:
            pickle.dump((name, args, kwargs), self.proc.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            self.proc.stdin.flush()
            status, value = pickle.load(self.proc.stdout)
        except (EOFError, OSError, pickle.UnpicklingError) as e:
            rc = self.close()
            raise RendererError(f"the OpenGL worker process ended (exit status {rc}) during "
                                f"{name}: {type(e).__name__}") from None
        if status == "error":
            raise value
        return value

    def close(self, timeout=10):
        r'''End the worker (closing its stdin ends its loop) -> its exit status'''
        for f in (self.proc.stdin, self.proc.stdout):
            try:
                f.close()
            except OSError:
                pass
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()


def call(name, *args, **kwargs):
    r'''Run the worker's function `name` with args and kwargs -> its value (see the module)'''
    with _LOCK:
        w = _WORKER[0] if _WORKER else None
        if w is not None and w.owner != os.getpid():      # a forked child: not ours to use
            _INHERITED.append(_WORKER.pop())
            w = None
        if w is not None and not w.alive():
            _WORKER.pop().close()
            w = None
        if w is None:
            w = Worker()
            _WORKER.append(w)
        return w.call(name, args, kwargs)


def shutdown():
    r'''End this process's worker, if it has one (also run at exit)'''
    with _LOCK:
        if _WORKER and _WORKER[0].owner == os.getpid():
            _WORKER.pop().close()


atexit.register(shutdown)


def _reply(out, value):
    try:
        data = pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)
    except Exception as e:  # an unpicklable value or exception: say what it was
        data = pickle.dumps(("error", RendererError(
            f"the OpenGL worker cannot send back its {type(value[1]).__name__}: {e}")))
    out.write(data)
    out.flush()


def main():
    r'''The worker's loop: requests on stdin until it closes'''
    channel = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)                     # C libraries' and print's output go to stderr
    sys.stdout = sys.stderr
    inp = sys.stdin.buffer
    functions = _functions()
    while True:
        try:
            name, args, kwargs = pickle.load(inp)
        except EOFError:
            return 0
        try:
            value = ("ok", functions[name](*args, **kwargs))
        except Exception as e:
            value = ("error", e)
        _reply(channel, value)


if __name__ == "__main__":
    sys.exit(main())
