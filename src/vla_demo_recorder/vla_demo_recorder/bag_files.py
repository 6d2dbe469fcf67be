"""Which file of a rosbag2 bag holds the messages, and in which storage (MCAP or sqlite3).

rosbag2 writes a folder with `metadata.yaml` and one data file per split: MCAP (`*.mcap`, the Jazzy
default) or sqlite3 (`*.db3`, the default before Iron, still written with `-s sqlite3`). The storage
is told by the file's first bytes, not its name, so a renamed or mislabelled file is not mistaken
for the other kind. No rclpy import.
"""
from __future__ import annotations

from pathlib import Path

from vla_demo_recorder.bag_writer import BagError, read_metadata_yaml

MCAP_MAGIC = b"\x89MCAP0\r\n"
SQLITE_MAGIC = b"SQLite format 3\x00"
DATA_SUFFIXES = (".mcap", ".db3")
_FOOTER_SIZE = 29  # opcode, length, summary start, summary offset start, summary crc


def storage_of(file: Path) -> str:
    """"mcap", "sqlite3" or "unknown", from the file's magic bytes."""
    with Path(file).open("rb") as f:
        head = f.read(len(SQLITE_MAGIC))
    if head.startswith(MCAP_MAGIC):
        return "mcap"
    if head.startswith(SQLITE_MAGIC):
        return "sqlite3"
    return "unknown"


def bag_file(bag: Path) -> Path:
    """The data file of a bag: `bag` itself when it is a file, else the one file metadata.yaml names,
    else the single `*.mcap` or `*.db3` in the folder (BagError when there is none or several)."""
    bag = Path(bag)
    if bag.is_file():
        return bag
    if not bag.is_dir():
        raise BagError(f"{bag} does not exist")
    listed = _listed_files(bag)
    if len(listed) > 1:
        raise BagError(f"{bag}: a bag split into {len(listed)} files is not supported")
    if listed:
        return listed[0]
    files = sorted(p for p in bag.iterdir() if p.suffix in DATA_SUFFIXES and p.is_file())
    if len(files) != 1:
        raise BagError(f"{bag}: expected exactly one .mcap or .db3 file, found {len(files)}")
    return files[0]


def _listed_files(bag: Path) -> list[Path]:
    """The data files metadata.yaml names that exist ([] without a readable metadata.yaml)."""
    try:
        names = read_metadata_yaml(bag)["relative_file_paths"]
        return [bag / Path(n).name for n in names if (bag / Path(n).name).is_file()]
    except (BagError, KeyError, TypeError):
        return []


def find_mcap(bag: Path) -> Path:
    """The bag's MCAP file; BagError naming the storage when it is something else."""
    file = bag_file(bag)
    kind = storage_of(file)
    if kind != "mcap" and file.stat().st_size >= len(MCAP_MAGIC):
        raise BagError(f"{file} is {_storage_text(kind)}, not MCAP")
    return file


def has_footer(mcap: Path) -> bool:
    """True when the file ends with a footer and the closing magic (a cleanly finished file)."""
    size = mcap.stat().st_size
    if size < len(MCAP_MAGIC) * 2 + _FOOTER_SIZE:
        return False
    with mcap.open("rb") as f:
        f.seek(size - len(MCAP_MAGIC) - _FOOTER_SIZE)
        tail = f.read()
    return tail[0] == 0x02 and tail[-len(MCAP_MAGIC):] == MCAP_MAGIC


def _storage_text(kind: str) -> str:
    return {"sqlite3": "a sqlite3 (.db3) rosbag2 file", "mcap": "an MCAP file"}.get(
        kind, "neither MCAP nor sqlite3 (unknown first bytes)")
