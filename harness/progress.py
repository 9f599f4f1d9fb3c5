r'''Progress of a campaign: a rich bar with ETA and stage on a terminal, plain lines otherwise

SYNOPSIS

    from harness.progress import Progress, job_stage

    with Progress(enabled=True) as p:            # stderr; a bar only when it is a terminal
        p.stage("choosing models", total=6)      # a campaign stage, with its own count
        p.advance("camera 15 CAHV mrcal: CAHVOR (2.1 s)")
        p.stage("jobs", total=9, watch=run_dir)  # the jobs' bar; workers' stages from run_dir
        p.advance("15/CAHV/dots/raycast: 3 ok")

    job_stage(job, "render + detect")            # in a worker: what the job is doing now

On a terminal (stream.isatty()) one rich bar per campaign stage: done / total,
elapsed, ETA and a description; during the jobs the description names what
every running job is doing (each worker writes its job's stage to
RUN_DIR/.progress/PID, polled twice a second). Elsewhere (CI logs, a pipe)
one plain line per finished item with elapsed time and ETA, and one line per
stage: nothing redraws, nothing is lost.
'''

import os
import sys
import threading
import time
from pathlib import Path

PROGRESS_DIR = ".progress"
POLL_SECONDS = 0.5


def _plain_eta(done, total, elapsed):
    if not done or total is None:
        return ""
    return f", ETA {elapsed / done * (total - done):.0f} s"


class Progress:
    r'''See the module docstring. enabled=False prints nothing.'''

    def __init__(self, enabled=True, stream=None, force_terminal=None):
        self.enabled = enabled
        self.stream = stream or sys.stderr
        tty = getattr(self.stream, "isatty", lambda: False)()
        self.rich = bool(enabled and (tty if force_terminal is None else force_terminal))
        self.bar = None
        self.task = None
        self.name = ""
        self.total = None
        self.done = 0
        self.t0 = time.monotonic()
        self._watch = None
        self._stop = threading.Event()
        self._thread = None
        self._last = ""
        if self.rich:
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )
            from rich.progress import (
                Progress as RichProgress,
            )
            from rich.table import Column
            console = Console(file=self.stream, force_terminal=True)

            def fixed(n):
                return Column(no_wrap=True, min_width=n)
            # stage 12 + bar 16 + count 7 + times 2 x 7 + "ETA" + gaps = 58 columns: the
            # description gets the rest of the line, cut with an ellipsis
            self.bar = RichProgress(
                TextColumn("[bold]{task.fields[stage]}", table_column=Column(
                    no_wrap=True, min_width=12, max_width=12, overflow="ellipsis")),
                BarColumn(bar_width=16), MofNCompleteColumn(table_column=fixed(7)),
                TimeElapsedColumn(table_column=fixed(7)), TextColumn("ETA"),
                TimeRemainingColumn(table_column=fixed(7)),
                TextColumn("{task.description}", table_column=Column(
                    no_wrap=True, overflow="ellipsis", max_width=max(10, console.width - 58))),
                console=console, transient=False)
            self.bar.start()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def stage(self, name, total=None, watch=None):
        r'''Start a campaign stage (a new bar on a terminal; a line otherwise). watch: a run
directory whose workers report their jobs' stages (job_stage)'''
        self._stop_watching()
        self.name, self.total, self.done = name, total, 0
        self._last = ""
        self.t0 = time.monotonic()
        if not self.enabled:
            return
        if self.bar is not None:
            if self.task is not None:     # the stage before is done: its bar full
                n = max(self.bar.tasks[-1].completed, 1)
                self.bar.update(self.task, description="", total=n, completed=n)
            self.task = self.bar.add_task("", total=total, stage=name)
        else:
            n = "" if total is None else f" ({total})"
            print(f"{name}{n} ...", file=self.stream, flush=True)
        if watch is not None and self.bar is not None:
            self._watch = Path(watch) / PROGRESS_DIR
            self._thread = threading.Thread(target=self._poll, daemon=True)
            self._thread.start()

    def advance(self, text, short=None):
        r'''One item of the current stage done; text says which and how it ended (short: the
same for the bar's one line, when text is long)'''
        self.done += 1
        if not self.enabled:
            return
        if self.bar is not None:
            self._last = short or text
            self.bar.update(self.task, advance=1, description=self._describe())
        else:
            el = time.monotonic() - self.t0
            n = f"{self.done}/{self.total}" if self.total is not None else str(self.done)
            print(f"[{n}] {text}  (elapsed {el:.0f} s{_plain_eta(self.done, self.total, el)})",
                  file=self.stream, flush=True)

    def note(self, text):
        r'''What the current stage is doing now (the description on a terminal; plain
output prints it only when there is no bar to redraw, so CI logs see each once)'''
        if not self.enabled:
            return
        if self.bar is not None:
            self._last = text
            self.bar.update(self.task, description=text)
        else:
            print(f"  {text}", file=self.stream, flush=True)

    def _describe(self):
        running = self._running()
        return "; ".join(running) if running else self._last

    def _running(self):
        if self._watch is None or not self._watch.is_dir():
            return []
        out = []
        for f in sorted(self._watch.iterdir()):
            try:
                out.append(f.read_text().strip())
            except OSError:      # the worker is rewriting it: the next poll reads it
                continue
        return [s for s in out if s]

    def _poll(self):
        while not self._stop.wait(POLL_SECONDS):
            if self.bar is not None and self.task is not None:
                self.bar.update(self.task, description=self._describe())

    def _stop_watching(self):
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None
            self._stop.clear()
        self._watch = None

    def close(self):
        self._stop_watching()
        if self.bar is not None:
            self.bar.stop()
            self.bar = None


def job_stage(job, stage):
    r'''Tell the parent's progress bar what this job is doing now: one line in
RUN_DIR/.progress/PID (only when the parent made that directory: local workers of a
campaign with a terminal; a Dask worker elsewhere writes nothing). stage None: done.'''
    run_dir = getattr(job, "run_dir", None)
    if not run_dir:
        return
    d = Path(run_dir) / PROGRESS_DIR
    if not d.is_dir():
        return
    path = d / str(os.getpid())
    try:
        if stage is None:
            path.unlink(missing_ok=True)
            return
        tmp = d / f".{os.getpid()}.tmp"
        # camera/family first: on an 80-column terminal the rest of the key is cut
        tmp.write_text(f"{'/'.join(job.key.split('/')[:2])}: {stage}")
        os.replace(tmp, path)
    except OSError:      # progress is a courtesy: it never ends a job
        pass


def watch_dir(run_dir):
    r'''Make RUN_DIR/.progress (empty) so that workers report their stages there'''
    d = Path(run_dir) / PROGRESS_DIR
    d.mkdir(parents=True, exist_ok=True)
    for f in d.iterdir():
        f.unlink(missing_ok=True)
    return d
