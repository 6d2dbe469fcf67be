"""Latest-value slots in shared memory: the one way the bridge talks to its helper processes (the
libfranka loop: `libfranka_slots.Slots`; the Franka Hand's: `hand_slots.HandSlots`). Plain Python.

No queues and no locks: each side writes only its own blocks and never waits for the other. A block
of several values is a seqlock (the writer makes its counter odd, writes, makes it even; a reader
retries while the counter is odd or changed), so a reader never sees half a command or half a state.
Single values (flags, request counters) are aligned 8-byte doubles, which x86-64 stores and loads
whole. A text is a seqlocked run of UTF-8 bytes. The file lives in /dev/shm; the creating side (the
ROS node) unlinks it on close, the helper when it finds the node gone.
"""

from __future__ import annotations

import mmap
import os
import tempfile

import numpy as np


def shm_dir() -> str:
    return "/dev/shm" if os.path.isdir("/dev/shm") else tempfile.gettempdir()


class SharedFile:
    """An mmap'ed file of `SIZE` bytes. Subclasses set SIZE and PREFIX, make their views in
    `_views()`, and name every view attribute in VIEWS (dropped before the map can close)."""

    SIZE = 0
    PREFIX = "vla-"
    VIEWS: tuple[str, ...] = ()

    def __init__(self, path: str, owner: bool):
        self.path = path
        self.owner = owner
        fd = os.open(path, os.O_RDWR)
        try:
            self._mm = mmap.mmap(fd, self.SIZE)
        finally:
            os.close(fd)
        self._views()

    def _views(self) -> None:
        raise NotImplementedError

    @classmethod
    def create(cls):
        fd, path = tempfile.mkstemp(prefix=cls.PREFIX, suffix=".shm", dir=shm_dir())
        try:
            os.ftruncate(fd, cls.SIZE)
        finally:
            os.close(fd)
        return cls(path, owner=True)

    @classmethod
    def attach(cls, path: str):
        if os.path.getsize(path) != cls.SIZE:
            raise ValueError(f"{path} is {os.path.getsize(path)} bytes, expected {cls.SIZE}: another layout")
        return cls(path, owner=False)

    def doubles(self, count: int, offset: int = 0) -> np.ndarray:
        return np.frombuffer(self._mm, dtype=np.float64, count=count, offset=offset)

    def close(self) -> None:
        for name in self.VIEWS:       # views into the map must go before the map itself can close
            setattr(self, name, None)
        try:
            self._mm.close()
        except BufferError:
            pass  # a copy still refers to it; the OS frees it with the process
        if self.owner:
            try:
                os.unlink(self.path)
            except FileNotFoundError:
                pass


def write_seqlock(seq: np.ndarray, block: np.ndarray, values) -> None:
    """Writer side: `values` into `block` under the counter `seq` (a 1-element view)."""
    seq[0] += 1.0
    block[:] = values
    seq[0] += 1.0


def read_seqlock(seq: np.ndarray, block: np.ndarray, out: np.ndarray, tries: int) -> np.ndarray | None:
    """A consistent copy of `block` into `out`, or None if every try met a write in progress."""
    for _ in range(tries):
        s1 = seq[0]
        if int(s1) % 2 == 0:
            np.copyto(out, block)
            if seq[0] == s1:
                return out
    return None


class Texts:
    """Seqlocked texts of at most `max_bytes` each, over three views of a SharedFile: the counters and
    lengths (float64, one per text) and the bytes (uint8, max_bytes per text)."""

    def __init__(self, names: tuple[str, ...], seq: np.ndarray, lengths: np.ndarray, data: np.ndarray,
                 max_bytes: int):
        self.names, self._seq, self._len, self._data, self._max = names, seq, lengths, data, max_bytes

    def write(self, which: str, text: str) -> None:
        i = self.names.index(which)
        data = text.encode("utf-8", "replace")[:self._max]
        self._seq[i] += 1.0
        self._data[i * self._max:i * self._max + len(data)] = np.frombuffer(data, dtype=np.uint8)
        self._len[i] = len(data)
        self._seq[i] += 1.0

    def read(self, which: str) -> str | None:
        """The text, or None while the writer is inside a write."""
        i = self.names.index(which)
        seq = self._seq
        for _ in range(1000):
            s1 = seq[i]
            if int(s1) % 2 == 0:
                n = int(self._len[i])
                data = self._data[i * self._max:i * self._max + n].tobytes()
                if seq[i] == s1:
                    return data.decode("utf-8", "replace")
        return None

    def even(self) -> None:
        """A writer killed inside a write leaves a counter odd: even them (at a new writer's start)."""
        for i in range(len(self._seq)):
            if int(self._seq[i]) % 2:
                self._seq[i] += 1.0
