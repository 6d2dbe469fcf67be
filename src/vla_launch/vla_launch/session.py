"""A launch file's processes, started from Python exactly as `vla launch <package> <file> a:=b` does.

For harnesses and tests (the evaluation, demonstration generation, graph tests): the same file, the
same parameter files and the same commands as a user's launch, supervised by the same `Launcher` in a
background thread. Output goes, prefixed like on a terminal, to a log file whose last lines come with
every error.

    with LaunchSession("vla_evaluation", "demo.launch.yaml", {"real_time_factor": 2.0},
                       log_path=out / "graph.log") as graph:
        ...
        graph.check()  # LaunchError when a process has ended, with its last output lines
"""
from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import threading
from collections.abc import Mapping
from pathlib import Path

from vla_launch import plan as plan_mod
from vla_launch.launch_file import LaunchPlan
from vla_launch.launcher import Launcher


class LaunchError(RuntimeError):
    """The launch could not start, a process of it ended, or it did not stop; the message says which."""


def argument_text(value: object) -> str:
    """A launch argument as `name:=value` text: booleans as true/false, floats with a decimal point."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    return str(value)


class LaunchSession:
    """Start with `start()` (or `with`), watch with `check()`, end with `stop()`."""

    def __init__(self, package: str | None, file: str, arguments: Mapping[str, object] | None = None, *,
                 env: Mapping[str, str | None] | None = None, log_path: str | Path | None = None,
                 sigterm_timeout: float = 5.0, sigkill_timeout: float = 5.0,
                 stop_stagger: float = 1.0) -> None:
        self.path = plan_mod.find_launch_file(package, file) if package else file
        self.arguments = {k: argument_text(v) for k, v in (arguments or {}).items()}
        self.env = dict(os.environ)
        for key, value in (env or {}).items():
            if value is None:
                self.env.pop(key, None)
            else:
                self.env[key] = value
        self.log_path = Path(log_path) if log_path is not None else None  # None: in the temporary folder
        self._timeouts = (sigterm_timeout, sigkill_timeout, stop_stagger)
        self._tmpdir: str | None = None
        self._plan: LaunchPlan | None = None
        self._log = None
        self._thread: threading.Thread | None = None
        self._rc: int | None = None
        self._stopping = False
        self.launcher: Launcher | None = None

    # ------------------------------------------------------------------------------- lifecycle
    def __enter__(self) -> LaunchSession:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def start(self) -> LaunchSession:
        self._tmpdir = tempfile.mkdtemp(prefix="vla_launch_")
        if self.log_path is None:
            self.log_path = Path(self._tmpdir) / "launch.log"
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._plan, specs = plan_mod.load(self.path, self.arguments, self._tmpdir)
        except Exception:
            self._cleanup()
            raise
        self._log = open(self.log_path, "a", buffering=1, encoding="utf-8")  # noqa: SIM115 - closed in stop()
        sigterm, sigkill, stagger = self._timeouts
        self.launcher = Launcher(specs, sigterm_timeout=sigterm, sigkill_timeout=sigkill,
                                 stop_stagger=stagger, stdout=self._log, stderr=self._log, env=self.env)
        self._thread = threading.Thread(target=self._run, name="vla-launch", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        self._rc = self.launcher.run()

    def stop(self, timeout: float = 60.0) -> int:
        """Stop every process like Ctrl-C on `vla launch` and wait; the launch's exit code."""
        if self._thread is None:
            return 0 if self._rc is None else self._rc
        self._stopping = True
        self.launcher.stop()
        self._thread.join(timeout)
        if self._thread.is_alive():
            raise LaunchError(f"{os.path.basename(self.path)} did not stop within {timeout:.0f} s; "
                              f"last output:\n{self.tail()}")
        self._thread = None
        self._cleanup()
        return self._rc if self._rc is not None else 1

    def _cleanup(self) -> None:
        if self._log is not None:
            self._log.close()
            self._log = None
        for f in self._plan.temp_files if self._plan else []:
            with contextlib.suppress(OSError):
                os.unlink(f)
        if self._tmpdir:  # temporary parameter files, and the log unless one was asked for
            shutil.rmtree(self._tmpdir, ignore_errors=True)

    # ------------------------------------------------------------------------------ watching
    @property
    def pids(self) -> dict[str, int]:
        """label -> pid of every process started (the latest one for a respawned label)."""
        return {label: pid for pid, label in self.launcher.labels.items()} if self.launcher else {}

    def ended(self) -> list[tuple[str, int]]:
        """(label, exit code) of every process that has ended so far."""
        return list(self.launcher.ended) if self.launcher else []

    def check(self) -> None:
        """LaunchError if a process has ended (or could not start) while the launch was not stopping."""
        if self.launcher is None or self._stopping:
            return
        done = self.ended() + [f for f in self.launcher.failures if f[1] == 127]
        if done:
            label, rc = done[0]
            how = f"exit code {rc}" if rc >= 0 else f"signal {-rc}"
            raise LaunchError(f"{label} ended ({how}); last output of {label}:\n{self.tail(label)}")

    def tail(self, label: str | None = None, lines: int = 25) -> str:
        """The last output lines of the launch, or of one process (`[<label>-<pid>]` lines)."""
        try:
            text = self.log_path.read_text(errors="replace").splitlines() if self.log_path else []
        except OSError:
            return ""
        if label is not None:
            text = [t for t in text if t.startswith(f"[{label}-") or f"[{label}-" in t[:80]]
        return "\n".join(text[-lines:])
