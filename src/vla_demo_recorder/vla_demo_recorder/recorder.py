"""Episode recording without ROS: one bag per episode, written by a background thread.

Why a thread: subscription callbacks must never wait on the disk (fsync, a slow USB stick), or the
middleware drops messages. Callbacks only enqueue serialized bytes; the writer thread writes them,
flushes complete chunks at least every `flush_period_s` and closes episodes. A bounded queue
(`max_queue_bytes`) turns a disk that cannot keep up into counted drops instead of unbounded memory.
A write error (disk full) ends the episode with a clear error; earlier bags are never touched.
`shutdown(drain_s=...)` bounds the close of an open episode: what is still queued after `drain_s` is
counted as dropped, so a process that must exit (Ctrl-C) still leaves a complete bag in time.
"""
from __future__ import annotations

import fcntl
import os
import queue
import re
import shutil
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from rosbags.interfaces import Qos
from vla_common.catalogue import Catalogue, default_catalogue
from vla_common.tasks import parse_task

from vla_demo_recorder.bag_writer import (
    BagError,
    BagExistsError,
    BagWriteError,
    BagWriter,
    EpisodeInfo,
    TypeRegistry,
)

_DIR_RE = re.compile(r"^ep(\d+)_")
_TASK_RE = re.compile(r"[A-Za-z0-9_]+/[A-Za-z0-9_]+")
_MAX_INDEX_TRIES = 1000
LOCK_NAME = ".recorder.lock"
LOCK_WAIT_S = 2.0


@contextmanager
def _folder_lock(folder: Path) -> Iterator[None]:
    """Hold `folder/.recorder.lock` (flock) while an episode index is chosen and its folder made, so
    recorders (threads or processes) sharing one output_dir number their episodes 1, 2, 3, ...
    Without the lock (a filesystem without flock, a stopped holder after LOCK_WAIT_S) the folder is
    still created atomically; only two episodes could then share an index."""
    try:
        fd = os.open(folder / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:
        yield
        return
    try:
        deadline = time.monotonic() + LOCK_WAIT_S
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    break
                time.sleep(0.005)
            except OSError:
                break
        yield
    finally:
        os.close(fd)  # releases the lock


class RecorderError(RuntimeError):
    """A request the recorder cannot honour (already recording, idle, bad task, bad folder)."""


def validate_task(task: str, catalogue: Catalogue | None = None) -> str:
    """The task's name (`bread:push_east` -> `bread/push_east`) when the catalogue (default: the
    default one) defines it; RecorderError says why not, listing the known classes or tasks and the
    files that define them. The one check of every episode's task."""
    text = task.strip().replace(":", "/")
    if not _TASK_RE.fullmatch(text):  # it names the episode's folder
        raise RecorderError(f"task {task!r} must look like '<object>/<action>', e.g. 'bread/push_east', "
                            "in letters, digits and _ (it names the episode's folder)")
    try:
        return parse_task(text, catalogue).name
    except ValueError as err:  # CatalogueError
        raise RecorderError(str(err)) from err


def _folder_problem(folder: Path) -> str:
    """'' when `folder` exists (it is created if needed) and is writable, else why not."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        return f"cannot create output_dir {folder}: {err.strerror or err}"
    if not os.access(folder, os.W_OK | os.X_OK):
        return f"output_dir {folder} is not writable"
    return ""


def next_episode_index(output_dir: Path) -> int:
    """1 + the largest `epNNNN_` index among the folders already in `output_dir`."""
    if not output_dir.is_dir():
        return 1
    indices = [int(m.group(1)) for p in output_dir.iterdir() if (m := _DIR_RE.match(p.name))]
    return max(indices, default=0) + 1


def episode_dir_name(index: int, task: str, when: datetime) -> str:
    return f"ep{index:04d}_{task.replace('/', '_')}_{when:%Y%m%d-%H%M%S}"


@dataclass
class RecorderState:
    recording: bool = False
    task: str = ""
    bag_path: str = ""
    episode_index: int = 0
    messages_written: int = 0
    bytes_written: int = 0
    messages_dropped: int = 0
    last_error: str = ""


@dataclass
class EpisodeResult:
    path: Path
    outcome: str
    index: int
    task: str
    messages: int
    bytes: int
    dropped: int
    counts: dict[str, int] = field(default_factory=dict)
    error: str = ""

    def summary(self) -> str:
        text = (f"{self.outcome} episode {self.index} ({self.task}): {self.messages} messages, "
                f"{self.bytes / 1e6:.1f} MB, {self.dropped} dropped, in {self.path}")
        return text + (f"; error: {self.error}" if self.error else "")


class _Episode:
    def __init__(self, writer: BagWriter, info: EpisodeInfo) -> None:
        self.writer = writer
        self.info = info
        self.dropped = 0
        self.failed = False
        self.write_until: float | None = None  # clock time after which queued messages are dropped
        self.result: EpisodeResult | None = None
        self.done = threading.Event()


_STOP = object()


class Recorder:
    """Thread-safe front end: `start`, `record` (from any callback thread), `stop`, `state`."""

    def __init__(self, output_dir: str | Path, *, flush_period_s: float = 0.5, fsync: bool = True,
                 max_queue_bytes: int = 1 << 30, delete_discarded: bool = False,
                 catalogue: Catalogue | None = None, log: Callable[[str, str], None] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        """`catalogue`: where episode tasks are defined (None: the default catalogue); `clock`: the
        clock of `shutdown`'s drain bound."""
        self.output_dir = Path(output_dir).expanduser().absolute()
        self.catalogue = catalogue
        self.flush_period_s = flush_period_s
        self.fsync = fsync
        self.max_queue_bytes = int(max_queue_bytes)
        self.delete_discarded = delete_discarded
        self._log = log or (lambda level, text: None)
        self._clock = clock
        self._registry = TypeRegistry()
        self._lock = threading.Lock()
        self._queue: queue.Queue = queue.Queue()
        self._queued_bytes = 0
        self._episode: _Episode | None = None
        self._last: _Episode | None = None
        self._last_error = ""
        self._thread = threading.Thread(target=self._run, name="bag_writer", daemon=True)
        self._thread.start()

    # -- control -------------------------------------------------------------------------------
    def start(self, task: str, note: str = "", topics: dict[str, tuple[str, list[Qos]]] | None = None,
              start_time_ns: int | None = None) -> Path:
        """Open a new episode bag; `topics` maps topic -> (type, offered QoS) known at start."""
        try:
            return self._start(validate_task(task, self.catalogue), note, topics, start_time_ns)
        except RecorderError as err:
            self._last_error = str(err)
            raise

    def check_output_dir(self) -> str:
        """'' when output_dir can take episodes, else the reason (reported at startup)."""
        return _folder_problem(self.output_dir)

    def set_output_dir(self, output_dir: str | Path) -> None:
        """Record the next episodes into `output_dir`; RecorderError (nothing changed) while recording
        or when the folder cannot be created or written."""
        path = Path(output_dir).expanduser().absolute()
        with self._lock:
            if self._episode is not None:
                raise RecorderError(f"recording episode {self._episode.info.index}; output_dir changes "
                                    "between episodes")
            if problem := _folder_problem(path):
                raise RecorderError(problem)
            self.output_dir = path

    def _start(self, task: str, note: str, topics: dict[str, tuple[str, list[Qos]]] | None,
               start_time_ns: int | None) -> Path:
        with self._lock:
            if self._episode is not None:
                ep = self._episode
                raise RecorderError(f"already recording episode {ep.info.index} ({ep.info.task}) to "
                                    f"{ep.writer.path}; stop or discard it first")
            if problem := self.check_output_dir():
                raise RecorderError(problem)
            with _folder_lock(self.output_dir):
                writer, info = self._open_episode(task, note, start_time_ns)
            try:
                for topic, (msgtype, qos) in (topics or {}).items():
                    try:
                        writer.add_topic(topic, msgtype, qos)
                    except BagWriteError:
                        raise
                    except BagError as err:
                        self._log("warn", f"not recording {topic}: {err}")
            except BagError as err:
                writer.abort(str(err))
                raise RecorderError(str(err)) from err
            self._episode = _Episode(writer, info)
            self._last_error = ""
            return writer.path

    def _open_episode(self, task: str, note: str, start_time_ns: int | None) -> tuple[BagWriter, EpisodeInfo]:
        """Create the next episode's bag. A folder another recorder created first is skipped (its
        index is taken): recorders sharing output_dir never write into each other's episodes."""
        index = next_episode_index(self.output_dir)
        now = datetime.now()
        start_ns = int(start_time_ns if start_time_ns is not None else time.time_ns())
        for _attempt in range(_MAX_INDEX_TRIES):
            info = EpisodeInfo(task=task, index=index, note=note, start_time_ns=start_ns, extra=self._extra())
            writer = BagWriter(self.output_dir / episode_dir_name(index, task, now), info,
                               flush_period_s=self.flush_period_s, fsync=self.fsync, registry=self._registry)
            try:
                return writer.open(), info
            except BagExistsError:
                index = max(index + 1, next_episode_index(self.output_dir))
            except BagError as err:
                raise RecorderError(str(err)) from err
        raise RecorderError(f"no free episode folder in {self.output_dir} after {_MAX_INDEX_TRIES} tries")

    def _extra(self) -> dict[str, str]:
        """Episode metadata beyond the fields: the catalogue that defines the task, unless the default."""
        if self.catalogue is None or self.catalogue is default_catalogue():
            return {}
        return {"catalogue": self.catalogue.where}

    def record(self, topic: str, msgtype: str, qos: list[Qos], t_ns: int, data: bytes) -> bool:
        """Queue one serialized message for the current episode; False if idle or dropped."""
        ep = self._episode
        if ep is None or ep.failed:
            return False
        size = len(data)
        with self._lock:
            if self._queued_bytes + size > self.max_queue_bytes:
                ep.dropped += 1
                return False
            self._queued_bytes += size
        self._queue.put((ep, topic, msgtype, qos, t_ns, data))
        return True

    def stop(self, keep: bool = True, end_time_ns: int | None = None, timeout: float = 30.0) -> EpisodeResult:
        """End the episode (kept or discarded); waits until its bag is closed."""
        with self._lock:
            ep = self._episode
            if ep is None:
                if self._last is not None and self._last.failed:
                    raise RecorderError(f"episode {self._last.info.index} already ended with an error: "
                                        f"{self._last.info.error}")
                raise RecorderError("not recording; start an episode first")
            self._episode = None
            self._last = ep
        self._queue.put((_STOP, ep, "kept" if keep else "discarded",
                         int(end_time_ns if end_time_ns is not None else time.time_ns())))
        if not ep.done.wait(timeout):
            raise RecorderError(f"episode {ep.info.index} is still being written after {timeout} s")
        assert ep.result is not None
        return ep.result

    def report_error(self, text: str) -> None:
        """Show an error found outside the recorder (e.g. by its node) as `state().last_error`."""
        self._last_error = text

    @property
    def recording(self) -> bool:
        return self._episode is not None

    def state(self) -> RecorderState:
        ep = self._episode or self._last
        st = RecorderState(recording=self._episode is not None, last_error=self._last_error)
        if ep is not None:
            st.task, st.bag_path, st.episode_index = ep.info.task, str(ep.writer.path), ep.info.index
            st.messages_written = ep.writer.message_count
            st.bytes_written = ep.writer.bytes_written
            st.messages_dropped = ep.dropped
        return st

    def shutdown(self, timeout: float = 30.0, drain_s: float | None = None) -> EpisodeResult | None:
        """Close a running episode as `interrupted` and stop the writer thread. With `drain_s`, the
        messages still queued `drain_s` after the call are not written but counted as dropped: the
        bag is closed in time however far behind the disk is."""
        result = None
        with self._lock:
            ep, self._episode = self._episode, None
            if ep is not None:
                self._last = ep
        if ep is not None:
            if drain_s is not None:
                ep.write_until = self._clock() + drain_s
            self._queue.put((_STOP, ep, "interrupted", time.time_ns()))
            ep.done.wait(timeout)
            result = ep.result
        self._queue.put(None)
        self._thread.join(timeout)
        return result

    # -- writer thread -------------------------------------------------------------------------
    def _run(self) -> None:
        open_eps: set[_Episode] = set()
        while True:
            try:
                item = self._queue.get(timeout=self.flush_period_s / 2)
            except queue.Empty:
                for ep in list(open_eps):
                    self._guard(ep, ep.writer.maybe_flush)
                continue
            if item is None:
                return
            if item[0] is _STOP:
                _, ep, outcome, end_ns = item
                open_eps.discard(ep)
                self._finish(ep, outcome, end_ns)
                continue
            ep, topic, msgtype, qos, t_ns, data = item
            late = ep.write_until is not None and self._clock() > ep.write_until
            with self._lock:
                self._queued_bytes -= len(data)
                if late and not ep.failed:
                    ep.dropped += 1  # shutting down: no time left to write it
            if late or ep.failed or ep.writer.closed:
                continue
            open_eps.add(ep)

            def write(ep=ep, topic=topic, msgtype=msgtype, qos=qos, t_ns=t_ns, data=data) -> None:
                if not ep.writer.has_topic(topic):
                    ep.writer.add_topic(topic, msgtype, qos)
                ep.writer.write(topic, t_ns, data)
            self._guard(ep, write)

    def _guard(self, ep: _Episode, fn: Callable[[], object]) -> None:
        """Run a write; an I/O error ends the episode (failed) with a clear message."""
        if ep.failed:
            return
        try:
            fn()
        except BagError as err:
            ep.failed = True
            ep.info.error = str(err)
            self._last_error = str(err)
            self._log("error", str(err))
            with self._lock:
                if self._episode is ep:
                    self._episode = None
                    self._last = ep
            if not ep.writer.closed:
                ep.writer.abort(str(err))
            self._finish(ep, "failed", time.time_ns())

    def _finish(self, ep: _Episode, outcome: str, end_ns: int) -> None:
        writer = ep.writer
        error = ep.info.error
        if ep.failed:
            outcome = "failed"
        else:
            ep.info.messages_dropped = ep.dropped
            try:
                writer.close(outcome, end_time_ns=end_ns)
            except BagError as err:
                outcome, error = "failed", str(err)
                self._last_error = error
                self._log("error", error)
        if outcome == "discarded" and self.delete_discarded:
            shutil.rmtree(writer.path, ignore_errors=True)
        ep.result = EpisodeResult(writer.path, outcome, ep.info.index, ep.info.task, writer.message_count,
                                  writer.bytes_written, ep.dropped, dict(writer.counts), error)
        ep.done.set()
