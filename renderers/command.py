r'''Bring your own renderer: an external program driven through request directories

SYNOPSIS

    from renderers.base import get_renderer, RenderSettings

    r = get_renderer("command", command=["python", "examples/external_renderer.py"])
    result = r.render(model, target.pattern(), Rt_cam_board, RenderSettings(spp=4))

    t = get_terrain_renderer("command", command=["python", "examples/external_renderer.py"])
    tr = t.render_terrain(model, terrain, Rt_ref_terrain, RenderSettings(spp=2))
    code = t.cell_shadows(terrain)       # the shadow check, as one rays request

    # inside the external program (if it is written in Python; camval installed):
    from renderers.protocol import read_request, write_image, serve
    req = read_request(sys.argv[1])      # .model, .pattern, .Rt_cam_board, .settings, .output
    write_image(req.output, image)       # (height, width) in [0,1]: 16-bit PNG or .npy

The protocol (request directory, exit codes, the persistent mode, the request
modes image/pinhole/rays and the camera models' unprojection equations) is
written down in docs/README-renderers.md; renderers.protocol reads and writes
it (its names are re-exported here).

Setup: how camval runs the program. Given at construction, or per render as
options of the same names (a campaign's [[renderer]] `setup` table, which
harness.stages merges into the options): they are recorded in a record's
settings but never name it, so a baseline still joins after the program moves
or its timeout changes. Every other option is passed to the program in
request.json (and names the records).

Failures (non-zero exit, a missing, unreadable or mis-sized image, values out
of [0,1] or NaN, a timeout, a persistent program that dies) raise
RendererError with the tail of the program's stderr (the last
protocol.STDERR_TAIL_LINES lines, at most protocol.STDERR_TAIL_BYTES bytes);
exit status protocol.EXIT_NOT_APPLICABLE (or a persistent answer
"not-applicable") raises RendererNotApplicable with the program's reason.
'''

import atexit
import collections
import dataclasses
import json
import os
import selectors
import shlex
import shutil
import subprocess
import tempfile
import threading
import time

import numpy as np

from .base import RendererError, RendererNotApplicable, RenderResult, RenderSettings
from .protocol import (  # noqa: F401  (re-exported: the protocol's names, as before)
    EXIT_NOT_APPLICABLE,
    MODES,
    OUTPUT_FORMATS,
    PERSISTENT_ENV,
    PIXEL_CONVENTION,
    PROTOCOL,
    PROTOCOL_VERSION,
    Request,
    RequestError,
    pattern_from_dict,
    pattern_to_dict,
    read_image,
    read_request,
    tail,
    write_image,
    write_request,
)

# options that say how to run the program, not what it renders: never passed to it,
# never part of a record's fullname (harness.records.settings_label reads only "options")
SETUP_KEYS = ("command", "timeout", "output_format", "version_command", "env",
              "keep_requests", "persistent", "mode", "pinhole_scale", "pinhole_samples",
              "pinhole_interpolation", "pinhole_measure_warp", "max_rays")


def _split(command, what="command"):
    if isinstance(command, str):
        command = shlex.split(command)
    if not isinstance(command, (list, tuple)) or not command:
        raise RendererError(f"renderer 'command' needs {what}=[program, args...]; "
                            f"got {command!r}")
    return [str(c) for c in command]


def setup_from_cli(command=None, items=()):
    r'''The setup given on a command line -> {key: value} for get_renderer("command", ...)

SYNOPSIS

    setup_from_cli("my-renderer --fast", ["timeout=60", 'env={"GPU": "0"}'])
    # {"command": ["my-renderer", "--fast"], "timeout": 60, "env": {"GPU": "0"}}

command: the program and its arguments as one string (split as a shell would);
items: KEY=VALUE, VALUE read as JSON when it parses (60, true, ["a", "b"],
{...}), else as a string.
'''
    setup = {}
    if command:
        setup["command"] = shlex.split(command)
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise RendererError(f"renderer setup {item!r}: expected KEY=VALUE")
        if key not in SETUP_KEYS:
            raise RendererError(f"renderer setup {key!r} is unknown; known: "
                                f"{', '.join(SETUP_KEYS)}")
        try:
            setup[key] = json.loads(value)
        except ValueError:
            setup[key] = value
    return setup


class _Persistent:
    r'''A program started once that answers requests line by line (see protocol)'''

    def __init__(self, command, env):
        self.command = command
        try:
            self.proc = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                         stderr=subprocess.PIPE, env=env)
        except OSError as e:
            raise RendererError(f"cannot start external renderer {command[0]!r}: {e}") from None
        self.stderr = collections.deque(maxlen=4 * 40)
        self._buf = b""
        self._thread = threading.Thread(target=self._drain, daemon=True)
        self._thread.start()
        self.lock = threading.Lock()

    def _drain(self):
        for line in iter(self.proc.stderr.readline, b""):
            self.stderr.append(line.decode("utf-8", "replace").rstrip("\n"))

    def stderr_tail(self):
        r'''The tail of what the program wrote to stderr, once the drain has caught up with
what is already in the pipe (the program logs before it answers; this must not lose it)'''
        deadline = time.monotonic() + 1.0
        with selectors.DefaultSelector() as sel:
            try:
                sel.register(self.proc.stderr.fileno(), selectors.EVENT_READ)
            except (ValueError, OSError):     # closed: the drain has read everything
                return tail("\n".join(self.stderr))
            while self._thread.is_alive() and sel.select(0) and time.monotonic() < deadline:
                time.sleep(0.005)
        time.sleep(0.005)    # the line the drain has just read, being appended
        return tail("\n".join(self.stderr))

    def ask(self, request_path, timeout):
        r'''-> the answer dict; raises RendererError (the process is then stopped)'''
        try:
            self.proc.stdin.write((json.dumps({"request": request_path}) + "\n").encode())
            self.proc.stdin.flush()
        except (BrokenPipeError, OSError):
            self.close()
            raise RendererError(f"persistent renderer {self.command[0]!r} is not running "
                                f"(exit {self.proc.returncode}); stderr:\n"
                                f"{self.stderr_tail()}") from None
        deadline = None if timeout is None else time.monotonic() + float(timeout)
        fd = self.proc.stdout.fileno()
        with selectors.DefaultSelector() as sel:
            sel.register(fd, selectors.EVENT_READ)
            while b"\n" not in self._buf:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0 or not sel.select(left):
                    self.close(kill=True)
                    raise RendererError(f"persistent renderer {self.command[0]!r} gave no "
                                        f"answer within {timeout} s (stopped); stderr:\n"
                                        f"{self.stderr_tail()}")
                chunk = os.read(fd, 65536)
                if not chunk:
                    self.close()
                    raise RendererError(f"persistent renderer {self.command[0]!r} exited "
                                        f"(exit {self.proc.returncode}) without answering; "
                                        f"stderr:\n{self.stderr_tail()}")
                self._buf += chunk
        line, self._buf = self._buf.split(b"\n", 1)
        try:
            answer = json.loads(line)
            if answer.get("status") not in ("ok", "not-applicable", "failed"):
                raise ValueError(f"status {answer.get('status')!r}")
        except (ValueError, AttributeError) as e:
            self.close()
            raise RendererError(f"persistent renderer {self.command[0]!r} answered "
                                f"{line[:200]!r}, not a JSON answer line ({e}); stdout is for "
                                f"answers only, log to stderr") from None
        return answer

    def close(self, kill=False):
        if self.proc.poll() is None and kill:
            self.proc.kill()
            self.proc.wait()
        if self.proc.poll() is None:
            try:
                self.proc.stdin.close()
                self.proc.wait(timeout=5)
            except (OSError, subprocess.TimeoutExpired):
                self.proc.kill()
                self.proc.wait()
        self._thread.join(timeout=5)
        for f in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            try:
                f.close()
            except OSError:
                pass


class CommandRenderer:
    r'''An external renderer program (see the module docstring and the protocol document)

ARGUMENTS (the setup; each may instead be given per render as an option)

- command: the program and its arguments, a list (or a string, split as a shell
  would); one-shot: "{request}" is replaced by the request path, else it is
  appended; persistent: run as given
- output_format: "png16" (default) or "npy"
- timeout: seconds per image before the program is killed (None: no limit)
- keep_requests: write requests into this directory and keep them (default: a
  temporary directory, removed after each render)
- env: extra environment variables for the program
- version_command: a command that prints the program's version (recorded in
  the records' versions.renderer)
- persistent: start the program once (per process and command) and send it
  requests on stdin (default False: one process per image)
- mode: "image" (default), "pinhole" or "rays" (the request mode)
- name: the name recorded in metadata (default "command")
'''

    name = "command"
    # boards (render) and terrain (render_terrain, cell_shadows): renderers.base.SCENE_KINDS
    scenes = ("board", "terrain")
    SETUP_KEYS = SETUP_KEYS      # campaigns keep these out of options (harness.campaign)

    def __init__(self, command=None, output_format="png16", timeout=None, keep_requests=None,
                 env=None, name="command", version_command=None, persistent=False,
                 mode="image", keep_dir=None, **more):
        self.setup = dict(command=command, output_format=output_format, timeout=timeout,
                          keep_requests=keep_requests or keep_dir, env=env,
                          version_command=version_command, persistent=persistent, mode=mode,
                          **more)
        self._check_setup(self.setup)
        self.command = None if command is None else _split(command)
        self.name = name
        self._versions = {}
        self._last_version = None
        self._procs = {}
        self._lock = threading.Lock()
        atexit.register(self.close)

    # --- setup ---------------------------------------------------------------------------
    @staticmethod
    def _check_setup(setup):
        unknown = set(setup) - set(SETUP_KEYS)
        if unknown:
            raise RendererError(f"command renderer: unknown setup {', '.join(sorted(unknown))}; "
                                f"known: {', '.join(SETUP_KEYS)}")
        if setup.get("command") is not None:
            cmd = _split(setup["command"])
            if shutil.which(cmd[0]) is None and not os.path.exists(cmd[0]):
                raise RendererError(f"renderer 'command': program {cmd[0]!r} not found "
                                    "(not on PATH and not a file)")
        if setup.get("output_format", "png16") not in OUTPUT_FORMATS:
            raise RendererError(f"command renderer: output format {setup['output_format']!r} "
                                f"is unknown; known: {', '.join(OUTPUT_FORMATS)}")
        if setup.get("mode", "image") not in MODES:
            raise RendererError(f"command renderer: mode {setup['mode']!r} is unknown; "
                                f"known: {', '.join(MODES)}")
        t = setup.get("timeout")
        if t is not None and (isinstance(t, bool) or not isinstance(t, (int, float)) or t <= 0):
            raise RendererError(f"command renderer: timeout {t!r}; expected seconds > 0")
        env = setup.get("env")
        if env is not None and not (isinstance(env, dict) and
                                    all(isinstance(v, str) for v in env.values())):
            raise RendererError(f"command renderer: env {env!r}; expected a table of strings")

    def _resolve(self, settings):
        r'''-> (setup dict, settings with the program's own options only)'''
        opts = dict(settings.options)
        setup = dict(self.setup)
        for k in SETUP_KEYS:
            if k in opts:
                setup[k] = opts.pop(k)
        self._check_setup(setup)
        if setup["command"] is None:
            raise RendererError("renderer 'command' needs a command: construct it with "
                                "command=[program, args...] or, in a campaign, "
                                "setup = { command = [...] }")
        setup["command"] = _split(setup["command"])
        return setup, dataclasses.replace(settings, options=opts)

    def version(self):
        r'''The version of the program of the last render (its version_command's output)'''
        if self._last_version is None:
            return self._version_of(self.setup)
        return self._last_version

    def _version_of(self, setup):
        cmd = setup.get("command")
        vc = setup.get("version_command")
        key = (json.dumps(cmd), json.dumps(vc))
        if key not in self._versions:
            prog = " ".join(os.path.basename(c) for c in _split(cmd)[:2]) if cmd else "(none)"
            v = f"external {prog}"
            if vc:
                try:
                    out = subprocess.run(_split(vc, "version_command"), capture_output=True,
                                         text=True, timeout=60)
                    text = (out.stdout.strip() or out.stderr.strip()).splitlines()
                    v += f": {text[0] if text else '(no output)'}"
                    if out.returncode != 0:
                        v += f" (version_command exit {out.returncode})"
                except (OSError, subprocess.SubprocessError) as e:
                    v += f" (version query failed: {e})"
            else:
                v += " (no version_command given)"
            self._versions[key] = v
        return self._versions[key]

    # --- running the program ---------------------------------------------------------------
    def _env(self, setup, persistent=False):
        env = dict(os.environ, **(setup.get("env") or {}))
        if persistent:
            env[PERSISTENT_ENV[0]] = PERSISTENT_ENV[1]
        return env

    def _run_one_shot(self, setup, req):
        command = setup["command"]
        if any("{request}" in c for c in command):
            cmd = [c.replace("{request}", req) for c in command]
        else:
            cmd = command + [req]
        timeout = setup.get("timeout")
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout,
                                  env=self._env(setup))
        except subprocess.TimeoutExpired as e:
            err = e.stderr.decode("utf-8", "replace") if isinstance(e.stderr, bytes) else e.stderr
            raise RendererError(f"external renderer {cmd[0]!r} timed out after {timeout} s; "
                                f"stderr:\n{tail(err)}") from None
        except OSError as e:
            raise RendererError(f"cannot run external renderer {cmd[0]!r}: {e}") from None
        if proc.returncode == EXIT_NOT_APPLICABLE:
            raise RendererNotApplicable(f"external renderer {cmd[0]!r}: not applicable: "
                                        f"{tail(proc.stderr)}")
        if proc.returncode != 0:
            raise RendererError(f"external renderer {cmd[0]!r} failed (exit "
                                f"{proc.returncode}); stderr:\n{tail(proc.stderr)}")
        return lambda: tail(proc.stderr)

    def _persistent(self, setup):
        key = (tuple(setup["command"]), json.dumps(setup.get("env") or {}, sort_keys=True))
        with self._lock:
            p = self._procs.get(key)
            if p is not None and p.proc.poll() is not None:
                p.close()
                p = None
            if p is None:
                p = self._procs[key] = _Persistent(list(key[0]), self._env(setup, True))
            return p

    def _run_persistent(self, setup, req):
        p = self._persistent(setup)
        with p.lock:
            answer = p.ask(req, setup.get("timeout"))
        name = setup["command"][0]
        if answer["status"] == "not-applicable":
            raise RendererNotApplicable(f"external renderer {name!r}: not applicable: "
                                        f"{answer.get('reason') or '(no reason given)'}")
        if answer["status"] == "failed":
            raise RendererError(f"external renderer {name!r} failed: "
                                f"{answer.get('reason') or '(no reason given)'}; stderr:\n"
                                f"{p.stderr_tail()}")
        return p.stderr_tail

    def close(self):
        r'''Stop the persistent programs this renderer started'''
        with self._lock:
            procs, self._procs = list(self._procs.values()), {}
        for p in procs:
            p.close()

    def _workdir(self, setup):
        keep = setup.get("keep_requests")
        if keep:
            os.makedirs(keep, exist_ok=True)
            return tempfile.mkdtemp(prefix="request-", dir=keep)
        return tempfile.mkdtemp(prefix="camval-command-")

    def _exchange(self, setup, write, read):
        r'''Write a request (write(workdir) -> request path), run the program, read the
output (read(workdir) -> value) -> (value, workdir or None)'''
        workdir = self._workdir(setup)
        try:
            req = write(workdir)
            run = self._run_persistent if setup.get("persistent") else self._run_one_shot
            stderr_tail = run(setup, req)
            try:
                value = read(workdir)
            except RendererError as e:
                raise RendererError(f"external renderer {setup['command'][0]!r}: {e}; "
                                    f"stderr:\n{stderr_tail()}") from None
        finally:
            if not setup.get("keep_requests"):
                shutil.rmtree(workdir, ignore_errors=True)
        return value, (workdir if setup.get("keep_requests") else None)

    def render(self, model, scene, Rt_cam_board, settings=None):
        settings = RenderSettings() if settings is None else settings
        setup, settings = self._resolve(settings)
        self._last_version = self._version_of(setup)
        t0 = time.perf_counter()
        mode = setup.get("mode", "image")
        extra = {}
        if mode == "image":
            fmt = setup.get("output_format", "png16")
            img, workdir = self._exchange(
                setup,
                lambda d: write_request(d, model, scene, Rt_cam_board, settings, fmt),
                lambda d: read_image(os.path.join(d, OUTPUT_FORMATS[fmt]), model.width,
                                     model.height))
        else:
            from . import command_modes
            img, workdir, extra, _ = command_modes.render(self, mode, setup, model, scene,
                                                           Rt_cam_board, settings)
        meta = dict(renderer=self.name, version=self._last_version,
                    settings=settings.as_dict(), seconds=time.perf_counter() - t0,
                    samples=settings.spp ** 2, command=setup["command"],
                    output_format=setup.get("output_format", "png16"), mode=mode,
                    persistent=bool(setup.get("persistent")), **extra)
        if workdir:
            meta["request_dir"] = workdir
        return RenderResult(image=np.asarray(img).astype(np.float32), metadata=meta)

    # --- terrain scenes (renderers.base.TerrainRenderer) ---------------------------------
    def render_terrain(self, model, terrain, Rt_ref_terrain=None, settings=None):
        r'''Render a targets.terrain.Terrain through the program -> TerrainRender

Rt_ref_terrain places the terrain in the model's frame (None: identity);
settings.options shadows, exposure, sky are the lighting (scene.json), the
rest the program's own options; settings None: K = 1, as the built-in
terrain renderers. image mode: range and shadow are the program's optional
range.npy / shadow.npy (None when it writes none); rays mode: its per-ray
range / shadow at each pixel's centre sample when K is odd (there is no
centre sample when K is even: None); pinhole mode: central cameras only,
range and shadow None.
'''
        from .base import TerrainRender
        from .protocol import TERRAIN_OUTPUTS, read_terrain_output, terrain_lighting

        settings = RenderSettings(spp=1) if settings is None else settings
        setup, settings = self._resolve(settings)
        light = terrain_lighting(settings.options)
        self._last_version = self._version_of(setup)
        t0 = time.perf_counter()
        mode = setup.get("mode", "image")
        if Rt_ref_terrain is None:
            Rt_ref_terrain = np.vstack((np.eye(3), np.zeros(3)))
        outputs, extra = {}, {}
        if mode == "image":
            fmt = setup.get("output_format", "png16")
            W, H = model.width, model.height

            def read(d):
                img = read_image(os.path.join(d, OUTPUT_FORMATS[fmt]), W, H)
                more = {k: read_terrain_output(os.path.join(d, f), k, W * H)
                        for k, f in TERRAIN_OUTPUTS.items()}
                return img, {k: v.reshape(H, W) for k, v in more.items() if v is not None}

            (img, outputs), workdir = self._exchange(
                setup,
                lambda d: write_request(d, model, terrain, Rt_ref_terrain, settings, fmt),
                read)
        else:
            from . import command_modes
            img, workdir, extra, outputs = command_modes.render(
                self, mode, setup, model, terrain, Rt_ref_terrain, settings)
        meta = dict(renderer=self.name, version=self._last_version,
                    settings=settings.as_dict(), seconds=time.perf_counter() - t0,
                    spp=settings.spp, samples=settings.spp ** 2, command=setup["command"],
                    output_format=setup.get("output_format", "png16"), mode=mode,
                    persistent=bool(setup.get("persistent")), **light,
                    outputs=sorted(outputs), terrain=terrain.as_dict(), **extra)
        if workdir:
            meta["request_dir"] = workdir
        return TerrainRender(image=np.asarray(img).astype(np.float32),
                             range=outputs.get("range"), shadow=outputs.get("shadow"),
                             metadata=meta)

    def cell_shadows(self, terrain):
        r'''The shadow check (renderers.terrain_shadows): the program's shadow code at every
triangle centroid, asked as one rays-mode request of vertical rays from above
(command_modes.shadow_rays) whatever the setup's mode -> (Ny-1, Nx-1, 2) uint8.
A program that does not do rays mode on terrain declines it: not-applicable.'''
        from . import command_modes

        setup, _ = self._resolve(RenderSettings(spp=1))
        self._last_version = self._version_of(setup)
        return command_modes.cell_shadows(self, setup, terrain)
