"""Make a bag whose writer died (SIGKILL, power cut, full disk) readable again, never losing its input.

The recorder flushes complete MCAP chunks at least every second, so a dead writer leaves a file
with a header, complete chunks (schemas, channels, messages) and at most one torn record at the end,
but no summary/footer and a metadata.yaml with zero counts. Recovery streams the file with the mcap
library's StreamReader, keeps every record of every complete chunk (a torn or corrupt chunk ends the
scan) and rewrites them into a fresh bag with rosbags (summary, footer, regenerated metadata.yaml
with correct counts), first in a work folder inside the bag. Only once that copy reads back with the
expected counts does it take the original's place; the original MCAP and metadata.yaml stay beside
it as `*.orig`. A bare .mcap outside a bag folder is recovered beside it (`<name>.recovered.mcap`).
Nothing is changed when nothing can be recovered or the storage is not MCAP (sqlite3 bags keep
their own journal). The episode metadata of the interim metadata.yaml is kept, with outcome
`recovered` whatever it said before (a `kept` episode whose file lost its end did not keep all of
it), except `discarded`; `error` says what was dropped and what the outcome was. Training leaves
recovered episodes out unless asked (vla_demo_recorder.dataset). No rclpy import.
"""
from __future__ import annotations

import os
import shutil
import struct
from dataclasses import dataclass, field
from pathlib import Path

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, DataEnd, Footer, Message, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from rosbags.rosbag2.metadata import parse_qos
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from vla_demo_recorder.bag_files import find_mcap, has_footer
from vla_demo_recorder.bag_writer import BagError, BagWriter, EpisodeInfo, read_metadata_yaml

_SCAN_ERRORS = (McapError, struct.error, EOFError, ValueError, KeyError, IndexError, OverflowError,
                MemoryError, UnicodeDecodeError)


@dataclass
class RecoveryReport:
    bag: Path
    complete: bool = False  # the file already had a footer
    chunks: int = 0
    messages: int = 0
    counts: dict[str, int] = field(default_factory=dict)
    bytes_scanned: int = 0
    bytes_dropped: int = 0
    stop_reason: str = ""
    output: Path | None = None  # the recovered MCAP file
    backup: Path | None = None  # where the original MCAP file now is (None: it did not move)
    outcome: str = ""  # the episode outcome the copy carries

    def summary(self) -> str:
        if self.complete:
            return f"{self.bag}: already complete (has a footer); nothing to do"
        topics = ", ".join(f"{t}: {n}" for t, n in self.counts.items()) or "none"
        text = (f"{self.bag}: recovered {self.messages} messages from {self.chunks} complete chunks "
                f"({topics}) into {self.output}; dropped {self.bytes_dropped} trailing bytes")
        if self.stop_reason:
            text += f" ({self.stop_reason})"
        if self.outcome:
            text += f"; episode outcome {self.outcome}"
        return text + f"; the original is kept as {self.backup or self.bag}"


def _rihs01(schema: Schema, known: dict[str, str]) -> str:
    if schema.name in known:
        return known[schema.name]
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(schema.data.decode(), schema.name))
    return store.hash_rihs01(schema.name)


def recover(bag: str | Path, force: bool = False) -> RecoveryReport:
    """Rewrite `bag` (folder or .mcap) from its complete chunks; returns what was kept.

    A complete bag is left alone unless `force`. BagError, with nothing changed, for storage other
    than MCAP, a file with nothing to recover, or a copy that does not read back.
    """
    bag = Path(bag).expanduser().absolute()
    mcap = find_mcap(bag)  # BagError for sqlite3 and unknown storage
    in_bag = bag.is_dir() or (mcap.parent / "metadata.yaml").is_file()
    report = RecoveryReport(bag=mcap.parent if in_bag else mcap)
    if has_footer(mcap) and not force:
        report.complete = True
        return report
    work = mcap.parent / f".recover-{mcap.name}"
    if work.exists():
        shutil.rmtree(work)  # our own leftover from an interrupted run; never the input
    try:
        out = _rewrite(mcap, work / (mcap.parent.name if in_bag else mcap.stem), report)
        if not report.messages:
            raise BagError(f"{mcap}: nothing to recover ({report.stop_reason or 'no complete chunk'}); "
                           "left unchanged")
        _verify(out.mcap_path, report)
        if in_bag:
            _swap_in(out, mcap, report)
        else:
            report.output = _free_name(mcap.with_name(f"{mcap.stem}.recovered.mcap"))
            os.replace(out.mcap_path, report.output)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return report


def _rewrite(mcap: Path, dest: Path, report: RecoveryReport) -> BagWriter:
    """Copy every record of the complete chunks of `mcap` into a new bag at `dest` (closed)."""
    old_custom, hashes = _old_metadata(mcap.parent)
    episode = EpisodeInfo.from_custom_data(old_custom)
    out = BagWriter(dest, episode, flush_period_s=1.0)
    try:
        out.open()
    except BagError as err:
        raise BagError(f"cannot write the recovered copy beside {mcap}: {err}") from err
    try:
        _scan(mcap, out, hashes, report)
        out.episode = _recovered_episode(episode, complete=has_footer(mcap), report=report)
        report.outcome = out.episode.outcome
        out.close(outcome=out.episode.outcome,
                  end_time_ns=out.last_ns or (episode.start_time_ns if episode else 0))
    except BaseException:
        out.abort()
        raise
    return out


def _recovered_episode(episode: EpisodeInfo | None, complete: bool, report: RecoveryReport) -> EpisodeInfo:
    """The episode metadata of the recovered copy. A file cut short becomes `recovered` whatever it
    said before (a `kept` episode whose file lost its end is not a complete demonstration), except
    `discarded`, which stays what the operator chose; a bag without episode metadata (another writer)
    gets one with an empty task, so that the copy too reads as recovered. A complete file (--force)
    keeps its outcome."""
    if episode is None:
        episode = EpisodeInfo(task="")
    before = episode.outcome
    if complete and before != "recording":
        return episode
    if before != "discarded":
        episode.outcome = "recovered"
    note = (f"recovered from {report.chunks} complete chunks; {report.bytes_dropped} trailing bytes dropped"
            + (f"; the outcome was {before!r}" if before not in ("recording", episode.outcome) else ""))
    episode.error = f"{episode.error}; {note}" if episode.error else note
    return episode


def _old_metadata(bag_dir: Path) -> tuple[dict[str, str], dict[str, str]]:
    """(custom_data, type hash by type) of the interim metadata.yaml, empty when unreadable."""
    try:
        meta = read_metadata_yaml(bag_dir)
        hashes = {t["topic_metadata"]["type"]: t["topic_metadata"]["type_description_hash"]
                  for t in meta.get("topics_with_message_count") or []
                  if t["topic_metadata"].get("type_description_hash")}
        return dict(meta.get("custom_data") or {}), hashes
    except (BagError, KeyError, TypeError, AttributeError):
        return {}, {}


def _scan(mcap: Path, out: BagWriter, hashes: dict[str, str], report: RecoveryReport) -> None:
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    size = mcap.stat().st_size
    good_end = 0
    with mcap.open("rb") as f:
        reader = StreamReader(f, emit_chunks=True, record_size_limit=size)
        try:
            for record in reader.records:
                records = breakup_chunk(record, validate_crc=True) if isinstance(record, Chunk) else [record]
                for rec in records:
                    if isinstance(rec, Schema):
                        schemas[rec.id] = rec
                    elif isinstance(rec, Channel):
                        channels[rec.id] = rec
                        schema = schemas[rec.schema_id]
                        definition = (schema.data.decode(), _rihs01(schema, hashes))
                        qos = parse_qos(rec.metadata.get("offered_qos_profiles", ""))
                        out.add_topic(rec.topic, schema.name, qos, definition=definition)
                    elif isinstance(rec, Message):
                        out.write(channels[rec.channel_id].topic, rec.log_time, rec.data)
                if isinstance(record, Chunk):
                    report.chunks += 1
                good_end = f.tell()
                if isinstance(record, (DataEnd, Footer)):
                    break
        except _SCAN_ERRORS as err:
            report.stop_reason = f"stopped at a torn or corrupt record at byte {good_end} of {size}: " \
                                 f"{type(err).__name__}"
    report.bytes_scanned = good_end
    report.bytes_dropped = max(0, size - good_end)
    report.messages = out.message_count
    report.counts = dict(out.counts)


def _verify(new_mcap: Path, report: RecoveryReport) -> None:
    """The copy must read back, complete, with the counts that were written."""
    try:
        with new_mcap.open("rb") as f:
            summary = make_reader(f).get_summary()
    except (McapError, OSError, ValueError) as err:
        raise BagError(f"the recovered copy {new_mcap} does not read back ({err}); original left unchanged") \
            from err
    counts: dict[str, int] = {}
    if summary is not None and summary.statistics is not None:
        for cid, n in summary.statistics.channel_message_counts.items():
            topic = summary.channels[cid].topic
            counts[topic] = counts.get(topic, 0) + n
    wanted = {t: n for t, n in report.counts.items() if n}
    if not has_footer(new_mcap) or {t: n for t, n in counts.items() if n} != wanted:
        raise BagError(f"the recovered copy {new_mcap} holds {counts}, expected {wanted}; "
                       "original left unchanged")


def _swap_in(out: BagWriter, mcap: Path, report: RecoveryReport) -> None:
    """Put the verified copy in the bag folder; the original files become `*.orig` (never deleted)."""
    bag_dir = mcap.parent
    target = bag_dir / out.mcap_path.name
    if target.exists() and target != mcap:
        raise BagError(f"{target} exists beside {mcap.name}; move one of them away; left unchanged")
    report.backup = _free_name(mcap.with_name(mcap.name + ".orig"))
    os.replace(mcap, report.backup)
    os.replace(out.mcap_path, target)
    report.output = target
    meta = bag_dir / "metadata.yaml"
    if meta.exists():
        os.replace(meta, _free_name(bag_dir / "metadata.yaml.orig"))
    os.replace(out.path / "metadata.yaml", meta)


def _free_name(path: Path) -> Path:
    """`path`, or `path.1`, `path.2`, ... : the first that does not exist (a backup never replaces one)."""
    candidate, n = path, 0
    while candidate.exists():
        n += 1
        candidate = path.with_name(f"{path.name}.{n}")
    return candidate
