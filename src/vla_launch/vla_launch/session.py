"""A launch file's processes, started from Python exactly as `vla launch <package> <file> a:=b` does.

For harnesses and tests (the evaluation, demonstration generation, graph tests): the same file, the
same parameter files and the same commands as a user's launch, supervised by the same `Launcher` in a
background thread. Output goes, prefixed like on a terminal, to a log file whose last lines come with
every error.

    with LaunchSession("vla_evaluation", "demo.launch.yaml", {"real_time_factor": 2.0},
                       log_path=out / "graph.log") as graph:
        ...
        graph.check()  # LaunchError when a process has ended, with its last output lines

`LaunchSession.of_processes([ProcessSpec(...), ...])` supervises given commands the same way (tests
that start nodes under a command prefix such as `ip netns exec`, each with its own environment).
"""
from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import threading
import time
from collections.abc import Mapping
from pathlib import Path

from vla_launch import plan as plan_mod
from vla_launch.launch_file import LaunchPlan
from vla_launch.launcher import Launcher, ProcessSpec


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
                 keep_going: bool = False) -> None:
        self.path = plan_mod.find_launch_file(package, file) if package else file
        self._specs: list[ProcessSpec] | None = None  # given processes instead of the launch file's
        self.keep_going = keep_going  # a process failing does not stop the others
        self.arguments = {k: argument_text(v) for k, v in (arguments or {}).items()}
        self.env = dict(os.environ)
        for key, value in (env or {}).items():
            if value is None:
                self.env.pop(key, None)
            else:
                self.env[key] = value
        self.log_path = Path(log_path) if log_path is not None else None  # None: in the temporary folder
        self._timeouts = (sigterm_timeout, sigkill_timeout)
        self._tmpdir: str | None = None
        self._plan: LaunchPlan | None = None
        self._log = None
        self._thread: threading.Thread | None = None
        self._rc: int | None = None
        self._stopping = False
        self.launcher: Launcher | None = None

    @classmethod
    def of_processes(cls, specs: list[ProcessSpec], **options) -> LaunchSession:
        """A session of the given processes (started in order) instead of a launch file's; the same
        options (env: the base environment, each spec's env overrides it)."""
        session = cls(None, "processes", **options)
        session._specs = list(specs)
        return session

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
            if self._specs is not None:
                specs = self._specs
            else:
                self._plan, specs = plan_mod.load(self.path, self.arguments, self._tmpdir)
        except Exception:
            self._cleanup()
            raise
        self._log = open(self.log_path, "a", buffering=1, encoding="utf-8")  # noqa: SIM115 - closed in stop()
        sigterm, sigkill = self._timeouts
        self.launcher = Launcher(specs, sigterm_timeout=sigterm, sigkill_timeout=sigkill,
                                 stdout=self._log, stderr=self._log, env=self.env,
                                 keep_going=self.keep_going)
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

    def exit_codes(self) -> dict[str, int]:
        """label -> exit code of each process that has ended (negative: killed by that signal)."""
        return dict(self.ended())

    def alive(self, label: str) -> bool:
        return label in self.pids and label not in self.exit_codes()

    def wait(self, label: str, timeout: float) -> int | None:
        """Wait up to `timeout` s for one process to end; its exit code, or None if still running."""
        end = time.monotonic() + timeout
        while label not in self.exit_codes() and time.monotonic() < end:
            time.sleep(0.1)
        return self.exit_codes().get(label)

    def describe(self, lines: int = 25) -> str:
        """Every process's state and last output lines, for assertion messages."""
        codes = self.exit_codes()
        parts = []
        for label in self.pids:
            state = f"exit code {codes[label]}" if label in codes else "running"
            parts.append(f"--- {label} ({state}):\n{self.tail(label, lines)}")
        return "\n".join(parts)

    def _tags(self, label: str) -> tuple[str, ...]:
        """The output tags (`[exec-n]`) of every process started under `label`, respawns included."""
        tags = self.launcher.tags if self.launcher else {}
        return tuple(f"[{tags[pid]}]" for pid, lab in self.launcher.labels.items() if lab == label) \
            if self.launcher else ()

    def output(self, label: str) -> list[str]:
        """Every output line of one process (not the launcher's lines about it), without the prefix."""
        prefix = self._tags(label)
        return [t.split("] ", 1)[1] for t in self.tail(label, lines=0).splitlines()
                if prefix and t.startswith(prefix)]

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
        """The last output lines of the launch, or of one process (lines with its `[exec-n]` tag)."""
        try:
            text = self.log_path.read_text(errors="replace").splitlines() if self.log_path else []
        except OSError:
            return ""
        if label is not None:
            tags = self._tags(label)
            text = [t for t in text if any(tag in t[:120] for tag in tags)]
        return "\n".join(text[-lines:] if lines else text)
