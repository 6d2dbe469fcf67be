"""The dead-man reaper of `vla launch`: a child that outlives a killed launch is SIGKILLed after a grace.

A SIGKILLed launch cannot escalate, and PR_SET_PDEATHSIG delivers one SIGTERM only. A node that is
stuck while it stops (Fast DDS 2.14's participant deletion can busy-wait for tens of seconds when the
other nodes of the graph leave at the same moment: eProsima/Fast-DDS#6513) would then live on. The
launcher therefore starts this small process in a process group of its own and writes one line per
child to its stdin, `<pid> <grace_s>`, and `exit` when it ends normally. EOF without `exit` means the
launch died: every child still alive after its grace (counted from the launch's death, when
PR_SET_PDEATHSIG sent SIGTERM) gets SIGKILL, with its process group (grandchildren included).

Standard library only and run with `python -I -S`, so it starts fast and needs no package on the path.
"""
from __future__ import annotations

import os
import signal
import sys
import time

POLL_S = 0.05


def alive(pid: int) -> bool:
    """True if `pid` exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            state = f.read().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state not in ("Z", "X")


def read_children(stream) -> tuple[dict[int, float], bool]:
    """The children announced on `stream` (pid -> grace s) and whether the launch said `exit`."""
    children: dict[int, float] = {}
    for line in stream:
        words = line.split()
        if words == ["exit"]:
            return children, True
        if len(words) == 2:
            try:
                children[int(words[0])] = float(words[1])
            except ValueError:
                continue
    return children, False


def reap(children: dict[int, float], log=None) -> list[int]:
    """Wait for each child's grace, then SIGKILL its group if it still runs; the pids killed."""
    t0 = time.monotonic()
    killed = []
    pending = dict(children)
    while pending:
        now = time.monotonic()
        for pid, grace in list(pending.items()):
            if not alive(pid):
                del pending[pid]
            elif now - t0 >= grace:
                for kill in (os.killpg, os.kill):
                    try:
                        kill(pid, signal.SIGKILL)
                    except (ProcessLookupError, PermissionError):
                        pass
                killed.append(pid)
                del pending[pid]
        time.sleep(POLL_S)
    if killed and log is not None:
        log(f"[WARN] [launch]: vla launch was killed; SIGKILLed {killed}, still running "
            f"{max(children[p] for p in killed):g} s after its SIGTERM\n")
    return killed


def _log(text: str) -> None:
    try:
        sys.stderr.write(text)
        sys.stderr.flush()
    except (OSError, ValueError):  # the launch's terminal or pipe may be gone with it
        pass


def main() -> int:
    for sig in (signal.SIGINT, signal.SIGHUP, signal.SIGPIPE):
        signal.signal(sig, signal.SIG_IGN)  # only the end of the launch (EOF) concerns the reaper
    children, clean = read_children(sys.stdin)
    if not clean:
        reap(children, _log)
    return 0


if __name__ == "__main__":
    sys.exit(main())
