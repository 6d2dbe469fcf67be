"""Make a bag whose writer died (SIGKILL, power cut, full disk) readable again.

The recorder flushes complete MCAP chunks at least every second, so a dead writer leaves a file
with a header, complete chunks (schemas, channels, messages) and at most one torn record at the end,
but no summary/footer and a metadata.yaml with zero counts. Recovery streams the file with the mcap
library's StreamReader, keeps every record of every complete chunk (a torn or corrupt chunk ends the
scan), rewrites them into a fresh bag with rosbags (summary, footer, regenerated metadata.yaml with
correct counts) and swaps it in place. The episode metadata of the interim metadata.yaml is kept,
with outcome `recovered`. No rclpy import.
"""
from __future__ import annotations

import os
import shutil
import struct
from dataclasses import dataclass, field
from pathlib import Path

from mcap.exceptions import McapError
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
    backup: Path | None = None

    def summary(self) -> str:
        if self.complete:
            return f"{self.bag}: already complete (has a footer); nothing to do"
        topics = ", ".join(f"{t}: {n}" for t, n in self.counts.items()) or "none"
        text = (f"{self.bag}: recovered {self.messages} messages from {self.chunks} complete chunks "
                f"({topics}); dropped {self.bytes_dropped} trailing bytes")
        if self.stop_reason:
            text += f" ({self.stop_reason})"
        return text


def _rihs01(schema: Schema, known: dict[str, str]) -> str:
    if schema.name in known:
        return known[schema.name]
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(schema.data.decode(), schema.name))
    return store.hash_rihs01(schema.name)


def recover(bag: str | Path, keep_original: bool = False, force: bool = False) -> RecoveryReport:
    """Rewrite `bag` (folder or .mcap) from its complete chunks; returns what was kept.

    A complete bag is left alone unless `force`. The original MCAP is deleted after the new one is
    in place, or kept as `<name>.mcap.orig` with `keep_original`.
    """
    bag = Path(bag).expanduser().absolute()
    mcap = find_mcap(bag)
    bag_dir = mcap.parent
    report = RecoveryReport(bag=bag_dir)
    if has_footer(mcap) and not force:
        report.complete = True
        return report

    old_custom: dict[str, str] = {}
    hashes: dict[str, str] = {}
    try:
        meta = read_metadata_yaml(bag_dir)
        old_custom = dict(meta.get("custom_data") or {})
        for t in meta.get("topics_with_message_count") or []:
            tm = t["topic_metadata"]
            if tm.get("type_description_hash"):
                hashes[tm["type"]] = tm["type_description_hash"]
    except (BagError, KeyError, TypeError):
        pass
    episode = EpisodeInfo.from_custom_data(old_custom)

    work = bag_dir / ".recover"
    if work.exists():
        shutil.rmtree(work)
    out = BagWriter(work / bag_dir.name, episode, flush_period_s=1.0)
    try:
        out.open()
    except BagError as err:
        shutil.rmtree(work, ignore_errors=True)
        raise BagError(f"cannot write the recovered copy inside {bag_dir}: {err}") from err
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    size = mcap.stat().st_size
    good_end = 0
    try:
        with mcap.open("rb") as f:
            reader = StreamReader(f, emit_chunks=True, record_size_limit=size)
            try:
                for record in reader.records:
                    records = breakup_chunk(record, validate_crc=True) if isinstance(record, Chunk) \
                        else [record]
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
                report.stop_reason = f"stopped at a torn or corrupt record: {type(err).__name__}"
        report.bytes_scanned = good_end
        report.bytes_dropped = max(0, size - good_end)
        report.messages = out.message_count
        report.counts = dict(out.counts)
        out.close(outcome="recovered" if episode and episode.outcome == "recording"
                  else (episode.outcome if episode else "recovered"),
                  end_time_ns=out.last_ns or (episode.start_time_ns if episode else 0))
    except BaseException:
        out.abort()
        shutil.rmtree(work, ignore_errors=True)
        raise

    new_mcap = out.mcap_path
    if keep_original:
        report.backup = mcap.with_name(mcap.name + ".orig")
        os.replace(mcap, report.backup)
    else:
        mcap.unlink()
    os.replace(new_mcap, bag_dir / new_mcap.name)
    os.replace(out.path / "metadata.yaml", bag_dir / "metadata.yaml")
    shutil.rmtree(work, ignore_errors=True)
    return report

