r'''The memory a render needs, checked before anything is allocated

SYNOPSIS

    from renderers.memory import check_render_memory, render_memory, memory_limit

    need = render_memory("raycast", model, RenderSettings(spp=16))
    need.total             # bytes, a lower bound of the render's peak
    need.parts             # {"image": bytes, "ray cache": bytes, ...}

    limit, source = memory_limit()      # bytes, "MemTotal" / "cgroup memory.max" / ...
    check_render_memory("raycast", model, settings)
    # raises RenderTooLargeError (a RendererError: a campaign records it as a
    # failed render; the command line prints one line and exits with status 2)

    pool = ImagePool()
    out, filled = pool.take((H, W), np.float32, (Nbands, Ntiles))   # a buffer nothing
    # else holds (or a new one) and the value each of its tiles holds (NaN: unknown)

A render is refused when the arrays it must allocate, counted from the image
size, the renderer path and the supersampling, exceed the memory this process
can ever have: the machine's RAM (MemTotal), lowered by a cgroup memory limit
or an address-space rlimit. The figure is the machine's capacity, not the
memory free at the moment, so that a campaign's records do not depend on what
else was running; a render that passes can still fail later for lack of free
memory (numpy's MemoryError is then its recorded reason).

The estimate is a lower bound, per path (bytes per model pixel, W x H):

- raycast: the float32 image (4); the edge-pixel mask (1, uint8) and the
  per-thread band of board points (~1 kB per image column) are not counted.
  No ray is cached (renderers/raycast.py): K costs no memory.
- the pinhole warps (osmesa, povray with camera="perspective", and their
  terrain versions): the warp's per-pixel rays, origin and direction in
  float64 (48, times n^2 for warp_samples n), its float32 maps (8 per
  sample), its pinhole coordinates and their gradients while it is built
  (48), and the pinhole image: at least W H warp_scale^2 pixels (its
  Jacobian's singular values are >= warp_scale and it covers every model
  pixel), float64 (8 each); POV-Ray renders it b times finer (K = n b,
  renderers.povray.split_supersampling) and reads that back in float64.
- povray with camera="mesh": the float64 image (8) and the edge mask (1).
- raycast_terrain: the pixel rays of K x K subsamples, origin and direction
  in float64 (48 K^2), the shading, range and code of each (17 K^2).
- terrain renderers besides: the image, the range and the shadow code (13).
- any other renderer (command, plugins): the float32 image (4). A renderer
  may declare its own lower bound as a method render_bytes(model, settings)
  -> {part: bytes}, used instead.
'''

import os
import resource
import sys
import threading
from dataclasses import dataclass, field

import numpy as np

from .base import RendererError, RenderSettings

WARP_RENDERERS = ("osmesa", "povray", "osmesa_terrain", "povray_terrain")
TERRAIN_RENDERERS = ("raycast_terrain", "povray_terrain", "osmesa_terrain")
_DEFAULT_OPTIONS = {"warp_scale": 1.0, "warp_samples": 1, "camera": "perspective"}


class RenderTooLargeError(RendererError):
    '''A render that needs more memory than this machine has (refused before it starts).'''


@dataclass(frozen=True)
class MemoryEstimate:
    r'''A lower bound of the memory a render allocates: parts {name: bytes}'''

    renderer: str
    width: int
    height: int
    parts: dict = field(default_factory=dict)

    @property
    def total(self):
        return int(sum(self.parts.values()))


def _options(renderer, settings):
    o = dict(_DEFAULT_OPTIONS)
    defaults = getattr(renderer, "defaults", None)
    if isinstance(defaults, dict):
        o.update(defaults)
    o.update(settings.options or {})
    return o


def _warp_parts(npx, o):
    scale = float(o.get("warp_scale") or 1.0)
    n = int(o.get("warp_samples") or 1)
    return {"warp rays": 48 * n * n * npx, "warp maps": 8 * n * n * npx,
            "warp construction": 48 * npx, "pinhole image": int(8 * scale * scale * npx)}


def render_memory(renderer, model, settings=None):
    r'''The lower bound of the memory rendering `model` needs (MemoryEstimate)

renderer: a renderer's name or a renderer object (its `name`, its `defaults`
and an optional render_bytes(model, settings) are used); settings: a
RenderSettings (default: RenderSettings()). Nothing of the image's size is
allocated.
'''
    settings = RenderSettings() if settings is None else settings
    name = renderer if isinstance(renderer, str) else str(getattr(renderer, "name", ""))
    W, H = int(model.width), int(model.height)
    npx = W * H
    K = int(settings.spp)
    own = None if isinstance(renderer, str) else getattr(renderer, "render_bytes", None)
    if callable(own):
        return MemoryEstimate(name, W, H, {k: int(v) for k, v in own(model, settings).items()})
    o = _options(renderer, settings)
    if name == "raycast":
        parts = {"image": 4 * npx}
    elif name == "raycast_terrain":
        parts = {"image, range, shadow": 13 * npx, "subsample rays": 48 * K * K * npx,
                 "subsample shading": 17 * K * K * npx}
    elif name in ("povray", "povray_terrain") and o.get("camera") == "mesh":
        parts = {"image": 8 * npx, "edge mask": npx}
    elif name in WARP_RENDERERS:
        parts = {"image": 4 * npx, **_warp_parts(npx, o)}
        if name.startswith("povray"):
            from .povray import split_supersampling
            _, b = split_supersampling(K)
            parts["pinhole image"] *= b * b
        if name in TERRAIN_RENDERERS:
            parts["image"] = 13 * npx
    else:
        parts = {"image": 4 * npx}
    return MemoryEstimate(name, W, H, parts)


def _cgroup_limit():
    for path in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            with open(path) as f:
                text = f.read().strip()
        except OSError:
            continue
        if text.isdigit():
            return int(text)
    return None


def memory_limit():
    r'''(bytes, source): the most memory this process can have

The machine's RAM (source "MemTotal"), or a cgroup memory limit ("cgroup
memory limit") or address-space rlimit ("RLIMIT_AS") when it is lower.
'''
    out = (os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"), "MemTotal")
    cg = _cgroup_limit()
    if cg is not None and cg < out[0]:
        out = (cg, "cgroup memory limit")
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY and soft < out[0]:
        out = (soft, "RLIMIT_AS")
    return out


def _gb(n):
    return f"{n / 1e9:.3g} GB"


def check_render_memory(renderer, model, settings=None, limit=None):
    r'''Raise RenderTooLargeError (one line) when the render cannot fit in memory

limit: bytes (default: memory_limit()). Returns the MemoryEstimate otherwise.
'''
    need = render_memory(renderer, model, settings)
    limit, source = memory_limit() if limit is None else (int(limit), "the limit given")
    if need.total > limit:
        parts = ", ".join(f"{k} {_gb(v)}" for k, v in need.parts.items() if v)
        raise RenderTooLargeError(
            f"a {need.width}x{need.height} image needs at least {_gb(need.total)} to render "
            f"with {need.renderer} ({parts}); this machine has {_gb(limit)} ({source})")
    return need



class ImagePool:
    r'''Image buffers handed out again once nothing else holds them, with what their tiles hold

SYNOPSIS

    pool = ImagePool(keep=2)
    out, filled = pool.take((H, W), np.float32, (Nbands, Ntiles))
    # out: uninitialised (or an earlier image), C-contiguous (H,W), writeable;
    # filled: float64 (Nbands, Ntiles), the value each tile of out holds throughout
    # (NaN: not known), kept with the buffer: the writer updates it as it writes.
    # ... fill out, then hand it to the caller read-only (out.flags.writeable = False);
    # once the caller drops out and every view of it, a later take of that shape
    # returns the same memory, writeable again, with its filled

A fresh array of an image's size is fresh memory: a 5120x3840 float32 image
is 79 MB, and the kernel faults in and zeroes every page of it as the render
first writes it (with numpy's transparent huge pages on a virtual machine, the
first such arrays of a process also fault in the host's memory behind them:
0.1-0.25 CPU-s each measured, against ~0.12 CPU-s for the whole render of such
an image). A renderer that writes every pixel of its image can take a buffer
from the pool instead: memory it used before, already mapped; and where it
knows a tile already holds the value it would write (the background around a
board, the same from pose to pose), it need not write it again (writing 79 MB
costs ~9 ms).

That knowledge holds only while nobody else writes into the buffer: the
renderer hands its images out read-only, so a caller that would change one
in place gets numpy's error instead (it copies first).

A buffer is free when nothing but the pool refers to it: the array handed out is
the buffer, every numpy view of it (a slice, a reshape) keeps a reference to it
(the view's .base), and so does anything holding either (a buffer export, a
RenderResult), so a buffer is never handed out again while any of them lives. The
pool keeps the buffers of one shape and dtype, the last asked for, at most
`keep` of them (2: the image a caller is still reading while the next is
rendered into the other); asking for another shape lets the others go. The
price: those buffers stay resident while the caller works on other things (a
paper-campaign job of a 5120x3840 camera rendered and detected in one process:
peak RSS 410 -> 415 MB for 1/CAHV/dots, 456 -> 505 MB for 3/CAHVORE/apriltag).
'''

    def __init__(self, keep=2):
        self.keep = int(keep)
        self._key = None
        self._buffers = []
        self._filled = []
        self._lock = threading.Lock()
        # the references to a buffer held only by the pool, as _references counts them
        probe = [np.empty(1)]
        self._idle = _references(probe, 0)

    def take(self, shape, dtype, tiles):
        r'''(array, filled): an uninitialised C-contiguous writeable array of shape and dtype,
a pooled buffer that nothing else holds, else a new one (pooled when fewer than `keep`
are); filled, float64 of shape tiles, what its tiles hold (NaN for a new buffer)'''
        key = (tuple(int(n) for n in shape), np.dtype(dtype), tuple(int(n) for n in tiles))
        with self._lock:
            if key != self._key:
                self._key = key
                self._buffers = []
                self._filled = []
            for i in range(len(self._buffers)):
                if _references(self._buffers, i) <= self._idle:
                    self._buffers[i].flags.writeable = True
                    return self._buffers[i], self._filled[i]
            out = np.empty(key[0], dtype=key[1])
            filled = np.full(key[2], np.nan)
            if len(self._buffers) < self.keep:
                self._buffers.append(out)
                self._filled.append(filled)
            return out, filled


def _references(buffers, i):
    r'''The reference count of buffers[i] (the list's reference, this call's argument and
any others)'''
    return sys.getrefcount(buffers[i])
