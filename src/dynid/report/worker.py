"""The report's figures, drawn beside the identification.

A plotted ``dynid identify`` run pays, on top of the identification, for matplotlib's import
(~0.6-1 s) and its figures (~1.5 s of CPU). None of it feeds the identification, so with a
second core it can run at the same time: :class:`WorkerJobs` starts one worker process when the
run begins; the worker imports matplotlib while the main process reads and identifies, receives
each figure's data as soon as they exist (the processing figure right after processing, the
validation figure after validation), draws it, and the main process copies the PNG into its
staging folder (:func:`dynid.io.output.staged_output`: a failure anywhere leaves no output). On
one core the worker only shares it: the gain needs a second core, free (bench/README.md, "TX40
identify: plot and import cost").

The worker is a fresh interpreter running this module only (not ``fork``: the main process holds
pinocchio and BLAS threads, which a fork copies in whatever state they are; and not
multiprocessing's ``spawn``, which runs the caller's ``__main__`` again: a script without a main
guard would start its identification twice), fed through two pipes. It runs the same functions
on the same arrays as :class:`InProcessJobs` (the PNG bytes are identical,
``tests/test_plot_worker.py``).
A job that fails in the worker fails the run the same way (a :class:`~dynid.errors.DynidError`,
one line ``dynid: error: ...`` from the command line).

:func:`report_jobs` chooses: the worker when a second CPU is available to this process and idle
(the one-minute load average leaves at least one CPU free), unless ``DYNID_PLOT_WORKER=0``
(``1`` asks for it whatever the CPUs and the load; POSIX only). On a busy machine the worker is
a loss: its interpreter, numpy and pickling cost 1-1.5 s of CPU more than drawing in process,
and the figures then wait for a core the identification also wants (bench/README.md).
``dynid identify`` asks for it (``identify(..., plot_worker=True)``); a library call of
:func:`dynid.pipeline.identify` starts no process unless asked.
"""

from __future__ import annotations

import importlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

from dynid.errors import DynidError

__all__ = ["InProcessJobs", "WorkerJobs", "report_jobs"]

# imported by the worker while it waits for its first jobs, in the order the jobs come
_WARMUP = ("matplotlib.figure", "matplotlib.backends.backend_agg", "dynid.report.plots")


def _resolve(func: str) -> Any:
    module, name = func.split(":")
    return getattr(importlib.import_module(module), name)


class InProcessJobs:
    """Figures and calls run in this process when their result is asked for (what a plotted run
    did before :class:`WorkerJobs`; one CPU)."""

    def __init__(self) -> None:
        self._jobs: dict[str, tuple[str, str, tuple, dict]] = {}
        self._done: dict[str, Any] = {}

    def submit_figure(self, key: str, func: str, *args: Any, **kwargs: Any) -> None:
        """Queue the figure ``func(*args, path, **kwargs)`` (``func``: ``"module:name"``) under
        ``key``, its file name."""
        self._jobs[key] = ("figure", func, args, kwargs)

    def submit_call(self, key: str, func: str, *args: Any, **kwargs: Any) -> None:
        """Queue ``func(*args, **kwargs)`` (picklable arguments and result) under ``key``."""
        self._jobs[key] = ("call", func, args, kwargs)

    def __contains__(self, key: str) -> bool:
        return key in self._jobs

    def write_figure(self, key: str, path: Path) -> Path:
        """Write the figure ``key`` to ``path``."""
        _, func, args, kwargs = self._jobs[key]
        _resolve(func)(*args, path, **kwargs)
        return path

    def result(self, key: str) -> Any:
        """The return value of the call ``key``."""
        if key not in self._done:
            _, func, args, kwargs = self._jobs[key]
            self._done[key] = _resolve(func)(*args, **kwargs)
        return self._done[key]

    def close(self, *, kill: bool = False) -> None:
        pass


class WorkerJobs(InProcessJobs):
    """The same jobs, run by one worker process (started when this object is made)."""

    def __init__(self) -> None:
        super().__init__()
        import subprocess
        import sys
        from multiprocessing.connection import Connection

        import dynid

        # two pipes, jobs down and replies up; the worker runs this module and nothing else (not the
        # caller's __main__, as multiprocessing's spawn would: a script without a main guard would run again)
        down_r, down_w = os.pipe()
        up_r, up_w = os.pipe()
        self._folder = Path(tempfile.mkdtemp(prefix="dynid-figures-"))  # the worker's PNG files, removed by close()
        root = str(Path(dynid.__file__).resolve().parents[1])  # the same dynid as this process
        code = (f"import sys; sys.path.insert(0, {root!r}); from dynid.report.worker import _main; "
                f"_main({down_r}, {up_w}, {str(self._folder)!r})")
        try:
            self._proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.DEVNULL,
                                          pass_fds=(down_r, up_w), close_fds=True)
        except OSError as exc:
            for fd in (down_r, down_w, up_r, up_w):
                os.close(fd)
            shutil.rmtree(self._folder, ignore_errors=True)
            raise DynidError(f"cannot start the plot worker process ({exc}); DYNID_PLOT_WORKER=0 draws the figures "
                             "in this process") from None
        os.close(down_r)
        os.close(up_w)
        self._out = Connection(down_w, readable=False)
        self._in = Connection(up_r, writable=False)
        self._replies: dict[str, tuple[str, Any]] = {}

    def _send(self, kind: str, key: str, func: str, args: tuple, kwargs: dict) -> None:
        self._jobs[key] = (kind, func, args, kwargs)
        try:
            self._out.send((kind, key, func, args, kwargs))
        except (OSError, EOFError, ValueError):  # the worker is gone: said when the result is asked for
            pass

    def submit_figure(self, key: str, func: str, *args: Any, **kwargs: Any) -> None:
        self._send("figure", key, func, args, kwargs)

    def submit_call(self, key: str, func: str, *args: Any, **kwargs: Any) -> None:
        self._send("call", key, func, args, kwargs)

    def _wait(self, key: str) -> Any:
        while key not in self._replies:
            try:
                rkey, status, payload = self._in.recv()
            except (OSError, EOFError):
                raise DynidError(f"the plot worker process ended before it sent {key} (exit code "
                                 f"{self._exit_code()})") from None
            self._replies[rkey] = (status, payload)
        status, payload = self._replies[key]
        if status != "ok":
            raise DynidError(payload)
        return payload

    def write_figure(self, key: str, path: Path) -> Path:
        path.write_bytes(Path(self._wait(key)).read_bytes())
        return path

    def result(self, key: str) -> Any:
        return self._wait(key)

    def _exit_code(self) -> int | None:
        import subprocess

        try:
            return self._proc.wait(5)
        except subprocess.TimeoutExpired:
            return None

    def close(self, *, kill: bool = False) -> None:
        """Stop the worker: it ends when its job pipe closes (between jobs); killed if it is still
        running one after 5 s, or at once with ``kill`` (the run failed: its figures are not wanted)."""
        if not hasattr(self, "_proc"):
            return
        self._out.close()
        if kill and self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
        elif self._proc.poll() is None and self._exit_code() is None:
            self._proc.kill()
            self._proc.wait()
        self._in.close()
        shutil.rmtree(self._folder, ignore_errors=True)

    def __del__(self) -> None:  # an outcome dropped without write_outputs: no process left behind
        try:
            self.close(kill=True)
        except Exception:
            pass


def report_jobs() -> InProcessJobs:
    """:class:`WorkerJobs` when this process may use more than one CPU and the one-minute load
    average leaves one of them idle (``DYNID_PLOT_WORKER=0``: never; ``1``: always), else
    :class:`InProcessJobs`."""
    choice = os.environ.get("DYNID_PLOT_WORKER", "").strip()
    if choice not in ("", "0", "1"):
        raise DynidError(f"DYNID_PLOT_WORKER must be 0 or 1, got {choice!r}")
    if choice == "0" or os.name == "nt":  # (the worker's pipes are POSIX file descriptors)
        return InProcessJobs()
    if choice == "":
        try:
            cpus = len(os.sched_getaffinity(0))
        except AttributeError:  # not Linux
            cpus = os.cpu_count() or 1
        try:
            load = os.getloadavg()[0]
        except (AttributeError, OSError):  # not available here: the CPU count decides alone
            load = 0.0
        if cpus < 2 or cpus - load < 1.0:
            return InProcessJobs()
    return WorkerJobs()


def _main(down: int, up: int, folder: str) -> None:  # pragma: no cover - runs in the worker process
    """The worker process's entry: job pipe ``down``, reply pipe ``up`` (file descriptors), and
    the folder to draw the figures in (the main process's, which reads and removes them)."""
    from multiprocessing.connection import Connection

    _serve(Connection(down, writable=False), Connection(up, readable=False), Path(folder))
    # nothing left to hand back: skip the interpreter's teardown of matplotlib and cvxpy (tenths of
    # a second the main process would wait for in close())
    import sys

    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


def _serve(jobs_in: Any, replies: Any, folder: Path) -> None:  # pragma: no cover - runs in the worker process
    """Receive every job as soon as it is sent (a thread: the main process never waits on a full
    pipe), import what the jobs need while none is waiting, run the jobs in order and reply
    ``(key, "ok", payload)`` (a figure: its file's path; small, so a reply never fills the pipe)
    or ``(key, "error", one-line message)``; end when the job pipe closes."""
    import queue
    import threading

    pending: queue.Queue = queue.Queue()

    def receive() -> None:
        while True:
            try:
                pending.put(jobs_in.recv())
            except (EOFError, OSError):
                pending.put(None)
                return

    threading.Thread(target=receive, daemon=True).start()
    warmup = list(_WARMUP)
    while True:
        if warmup and pending.empty():
            try:
                importlib.import_module(warmup.pop(0))
            except ImportError:  # an optional extra not installed: the job that needs it says so
                pass
            continue
        job = pending.get()
        if job is None:
            return
        kind, key, func, args, kwargs = job
        try:
            if kind == "figure":
                path = folder / key
                _resolve(func)(*args, path, **kwargs)
                payload: Any = str(path)
            else:
                payload = _resolve(func)(*args, **kwargs)
            reply = (key, "ok", payload)
        except DynidError as exc:
            reply = (key, "error", str(exc))
        except Exception as exc:  # noqa: BLE001 - any failure ends the run as one line, not a traceback
            reply = (key, "error", f"{key} failed in the plot worker: {type(exc).__name__}: {exc}")
        try:
            replies.send(reply)
        except (OSError, EOFError):
            return
