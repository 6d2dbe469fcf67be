"""A loaded machine for determinism tests: two processes that spin a core each while a block runs."""
import os
import subprocess
import sys


class BusyLoops:
    """Two processes that spin a core each, for as long as the block runs."""

    def __enter__(self):
        env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
        self.procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"], env=env) for _ in range(2)]
        return self

    def __exit__(self, *exc):
        for p in self.procs:
            p.kill()
            p.wait()
