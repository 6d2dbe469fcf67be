"""Loaded by every Python started with this folder first on PYTHONPATH (test_runtime_imports.py):
makes the modules named in $VLA_IMPORT_BLOCKED (comma-separated, submodules included) unimportable
and records, one JSON line each in $VLA_IMPORT_BLOCKER_LOG, that it is installed in this process and
every import it refused. Python runs sitecustomize after the .pth files, before any user code.
"""
import json
import os
import sys

_BLOCKED = frozenset(n for n in os.environ.get("VLA_IMPORT_BLOCKED", "").split(",") if n)
_LOG = os.environ.get("VLA_IMPORT_BLOCKER_LOG")


def _record(event: str, name: str = "") -> None:
    if _LOG:
        with open(_LOG, "a") as f:
            f.write(json.dumps({"pid": os.getpid(), "event": event, "name": name}) + "\n")


class _Blocker:
    """A meta-path finder ahead of the real ones: refuses the blocked names, defers everything else."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname.partition(".")[0] in _BLOCKED:
            _record("blocked", fullname)
            raise ImportError(f"import of {fullname} blocked by test/runtime_blocker", name=fullname)
        return None


sys.meta_path.insert(0, _Blocker())
_record("installed", ",".join(sorted(_BLOCKED)))
