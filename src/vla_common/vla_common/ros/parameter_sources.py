"""Where a node's parameter overrides came from: which `--params-file` section or `-p`, and whether
that source is the node's own or shared with other nodes. rcl merges them all into one dictionary, so
the parameter table (`parameters.py`) asks this module before it refuses or warns:

- a name under a section keyed by the node itself (`/arm/left`, `panda_bridge`, `/**/left`), given
  with `-p`, or in the node's constructor is meant for this node: an unknown one is refused;
- a name under a shared section (its last part a wildcard: `/**`, `/arm/*`, `/arm/**`) may belong to
  another node that reads the same file, a common ROS pattern: an unknown one is only warned about;
- a parameter file none of whose sections applies to the node (`panda_bridg:`, a misspelt key) is
  warned about, naming its keys: several nodes are often given one file with a section each, and a
  node whose section is absent runs on its defaults, so it is not refused.

Sections match as rcl matches them: a key without a leading `/` gets one, `/*` is one name and `/**`
any number, and a key may also nest namespaces (`arm: {left: {ros__parameters: ...}}`). The command
line a context was initialised with is remembered per context (`remember`, called by `run_node`),
since rclpy keeps only the merged overrides. No rclpy import: this is plain data.
"""

from __future__ import annotations

import difflib
import re
import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from vla_common.safe_yaml import YamlFileError, load_yaml

PARAMS_KEY = "ros__parameters"
MAX_FILE_BYTES = 1 << 20
_ARGUMENTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_KEY = re.compile(r"[\w/*]+")


@dataclass(frozen=True)
class Section:
    """The names one source gives: `origin` is a file path or "-p"; `key` the section's key."""

    origin: str
    key: str
    names: frozenset[str]

    @property
    def shared(self) -> bool:
        """True when the key's last part is a wildcard: the section is meant for several nodes."""
        return self.origin != "-p" and "*" in self.key.rstrip("/").rsplit("/", 1)[-1]

    def where(self) -> str:
        return "with -p" if self.origin == "-p" else f"under '{self.key}' in {self.origin}"


@dataclass(frozen=True)
class Sources:
    """The sections that apply to one node, and the parameter files of which none does."""

    sections: tuple[Section, ...]
    unmatched_files: tuple[tuple[str, tuple[str, ...]], ...]  # (path, its keys)


def remember(context: object, argv: Sequence[str]) -> None:
    """Keep the command line `context` was initialised with (rclpy does not)."""
    _ARGUMENTS[context] = list(argv)


def arguments_of(context: object) -> list[str] | None:
    """The command line remembered for `context`, or None when it is not known."""
    return _ARGUMENTS.get(context)


def ros_arguments(argv: Sequence[str]) -> list[str]:
    """The arguments rcl reads: those after each `--ros-args`, up to `--` or the end."""
    out, inside = [], False
    for a in argv:
        if a == "--ros-args":
            inside = True
        elif a == "--" and inside:
            inside = False
        elif inside:
            out.append(a)
    return out


def key_matches(key: str, node_fqn: str) -> bool:
    """Whether a parameter file's section key applies to the node `node_fqn`, as rcl decides it."""
    if not _KEY.fullmatch(key):
        return False
    if not key.startswith("/"):
        key = "/" + key
    return re.fullmatch(key.replace("/*", r"(/\w+)"), node_fqn) is not None


def file_sections(path: str) -> dict[str, frozenset[str]]:
    """Section key -> parameter names (nested maps as dotted names) of a ROS parameter file."""
    doc = load_yaml(Path(path), MAX_FILE_BYTES, "parameter file")
    out: dict[str, frozenset[str]] = {}

    def walk(node: object, key: str) -> None:
        if not isinstance(node, dict):
            return
        for k, v in node.items():
            if k == PARAMS_KEY:
                out[key] = frozenset(out.get(key, frozenset()) | set(_dotted(v)))
            else:
                walk(v, f"{key}/{k}" if key else str(k))

    walk(doc, "")
    return out


def _dotted(params: object, prefix: str = "") -> list[str]:
    if not isinstance(params, dict):
        return []
    names = []
    for k, v in params.items():
        name = f"{prefix}{k}"
        names += _dotted(v, name + ".") if isinstance(v, dict) else [name]
    return names


def sources_for(node_fqn: str, argv: Sequence[str]) -> Sources:
    """The `-p` and parameter-file sections of `argv` that apply to `node_fqn`, in order."""
    sections, unmatched = [], []
    args = ros_arguments(argv)
    for flag, value in zip(args, args[1:]):
        if flag in ("-p", "--param") and ":=" in value:
            sections.append(Section("-p", "/**", frozenset([value.split(":=", 1)[0]])))
        elif flag == "--params-file":
            try:
                keys = file_sections(value)
            except (YamlFileError, OSError):
                continue  # rcl read it already; what this module cannot read it leaves to rcl
            applied = [Section(value, k, names) for k, names in keys.items() if key_matches(k, node_fqn)]
            sections += applied
            if not applied:
                unmatched.append((value, tuple(keys)))
    return Sources(tuple(sections), tuple(unmatched))


def closest_key(keys: Sequence[str], node_fqn: str) -> str | None:
    """The key most like the node's name or full name (a misspelt key), if any is close."""
    targets = (node_fqn.rsplit("/", 1)[-1], node_fqn.strip("/"))
    best = None
    for k in keys:
        score = max(difflib.SequenceMatcher(None, k.strip("/"), t).ratio() for t in targets)
        if score >= 0.6 and (best is None or score > best[0]):
            best = (score, k)
    return best[1] if best else None
