"""Read a small YAML file from a path that anyone may have chosen (a parameter set by a DDS peer).

- Only a regular file is read (not /dev/zero, a FIFO, a socket or a folder), opened without blocking
  and read up to a size bound, so a path can neither exhaust memory nor hang the caller.
- The loader is PyYAML's safe loader with no aliases or anchors (`&a`, `*a`: a 600-byte alias bomb
  expands to gigabytes), no merge keys, no duplicate keys (a second `bread:` would silently replace
  the first), a bounded nesting depth, and nothing but plain data types.
- Every refusal is a `YamlFileError` naming the file and where in it (line, column, the key), never
  the file's content: the file may be anyone's, and the message goes back to whoever chose the path.
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path

import yaml

MAX_DEPTH = 32
Lines = dict[tuple[str, ...], int]  # the line of each key and item, by its path (load_yaml_lines)


class YamlFileError(ValueError):
    """The file cannot be read as the small YAML document it should be; the text quotes no content."""


class UnreadableError(YamlFileError):
    """The path is not a regular file of the allowed size that can be opened; `reason` says which."""

    def __init__(self, message: str, reason: str):
        super().__init__(message)
        self.reason = reason


def key_name(key: object) -> str:
    """A mapping key as an error names it: quoted, at most 40 characters."""
    text = repr(key) if isinstance(key, str) else f"{type(key).__name__} key"
    return text if len(text) <= 40 else text[:37] + "...'"


def read_file(path: Path, max_bytes: int, what: str = "file") -> bytes:
    """The bytes of the regular file `path`, at most `max_bytes`; YamlFileError otherwise."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | os.O_NOCTTY)
    except (OSError, ValueError) as err:  # ValueError: a NUL in the path
        raise UnreadableError(f"cannot read {what} {path}: {_reason(err)}", _reason(err)) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise UnreadableError(f"{what} {path} is not a regular file", "not a regular file")
        if st.st_size > max_bytes:
            raise UnreadableError(f"{what} {path} is {st.st_size} bytes, more than the {max_bytes} "
                                  "allowed", f"more than {max_bytes} bytes")
        chunks, size = [], 0
        while size <= max_bytes:
            chunk = os.read(fd, max_bytes + 1 - size)
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        if size > max_bytes:
            raise UnreadableError(f"{what} {path} grew beyond the {max_bytes} bytes allowed while "
                                  "being read", f"more than {max_bytes} bytes")
        return b"".join(chunks)
    except OSError as err:
        raise UnreadableError(f"cannot read {what} {path}: {_reason(err)}", _reason(err)) from None
    finally:
        os.close(fd)


def load_yaml(path: Path, max_bytes: int, what: str = "file") -> object:
    """The one YAML document in the regular file `path` (see the module's rules)."""
    return _load(path, max_bytes, what, False)[0]


def load_yaml_lines(path: Path, max_bytes: int, what: str = "file") -> tuple[object, Lines]:
    """As `load_yaml`, with the line of each mapping key and sequence item: {path: line}, a path being
    the keys and indices down to it, each as str (`("settings", "Seen")`, `("strategies", "1")`; `()`:
    the document), so that a schema's error can say file:line."""
    return _load(path, max_bytes, what, True)


def _load(path: Path, max_bytes: int, what: str, lines: bool) -> tuple[object, Lines]:
    data = read_file(path, max_bytes, what)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise YamlFileError(f"{what} {path} is not UTF-8 text (byte {err.start})") from None
    loader = _StrictLoader(text)
    try:
        node = loader.get_single_node()
        value = loader.construct_document(node) if node is not None else None
        return value, (_node_lines(node) if lines and node is not None else {})
    except _RefusedError as err:
        raise YamlFileError(f"{what} {path}: {_at(err.mark)}{err.reason}") from None
    except yaml.MarkedYAMLError as err:
        mark = err.problem_mark or err.context_mark
        problem = _redacted(err.problem or "")
        raise YamlFileError(f"{what} {path}: invalid YAML: {_at(mark)}{problem}") from None
    except yaml.YAMLError:
        raise YamlFileError(f"{what} {path}: invalid YAML") from None
    except (ValueError, TypeError, OverflowError, RecursionError, MemoryError) as err:
        # e.g. an integer of 100 000 digits: the constructor's own error, whose text is not ours to pass on
        raise YamlFileError(f"{what} {path}: invalid YAML: a value cannot be read ({type(err).__name__})") \
            from None
    finally:
        loader.dispose()


def _node_lines(root: yaml.Node) -> Lines:
    """{path: line} of every key and item under `root` (nesting is bounded by the loader)."""
    out: Lines = {(): root.start_mark.line + 1}
    todo: list[tuple[tuple[str, ...], yaml.Node]] = [((), root)]
    while todo:
        where, node = todo.pop()
        if isinstance(node, yaml.MappingNode):
            for key, value in node.value:
                here = (*where, str(key.value) if isinstance(key, yaml.ScalarNode) else "?")
                out[here] = key.start_mark.line + 1
                todo.append((here, value))
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                here = (*where, str(i))
                out[here] = item.start_mark.line + 1
                todo.append((here, item))
    return out


class _RefusedError(Exception):
    def __init__(self, mark, reason: str):
        super().__init__(reason)
        self.mark, self.reason = mark, reason


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader without aliases, anchors, merge keys or duplicate keys, nested at most MAX_DEPTH."""

    def __init__(self, stream) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None) is not None:
            raise _RefusedError(event.start_mark, "anchors and aliases (& and *) are not allowed")
        if self._depth >= MAX_DEPTH:
            raise _RefusedError(event.start_mark, f"nested deeper than {MAX_DEPTH} levels")
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            first: dict = {}
            for key_node, _value in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    raise _RefusedError(key_node.start_mark, "merge keys (<<) are not allowed")
                key = self.construct_object(key_node, deep=True)
                try:
                    seen = first.get(key)
                except TypeError:
                    raise _RefusedError(key_node.start_mark, "a mapping key must be a plain value") from None
                if seen is not None:
                    twice = f"key {key_name(key)} appears twice (first on line {seen})"
                    raise _RefusedError(key_node.start_mark, twice)
                first[key] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep)


def _at(mark) -> str:
    return f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""


def _redacted(problem: str) -> str:
    """PyYAML's problem text without what it quotes from the file (a tag, a token), except token
    kinds such as '<scalar>' and single characters."""
    return re.sub(r"'([^']*)'", lambda m: m.group(0) if m.group(1).startswith("<") or len(m.group(1)) <= 2
                  else "'...'", problem)


def _reason(err: BaseException) -> str:
    return err.strerror if isinstance(err, OSError) and err.strerror else type(err).__name__
