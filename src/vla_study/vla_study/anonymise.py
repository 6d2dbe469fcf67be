"""A shareable copy of a study folder with participant ids replaced by pseudonyms.

    python -m vla_study.anonymise --src out/study --dest out/study_shared --key ~/private/key.csv
The copy holds the same trials and answers under P01, P02, ... (in the order participants first
appear), file names included, and study.json keeps only the protocol's file name (its path may name a
person or a site). The key (pseudonym, original id) goes to --key, which must lie outside both
folders: keep it apart from the data, or delete it, as the ethics approval says. Simulated
participants (sim:N) keep their ids. The source folder is never changed; an existing --dest is
refused (nothing is overwritten).
"""
from __future__ import annotations

import argparse
import csv
import json
import shutil
from pathlib import Path

from vla_study.trial import file_stem


def anonymise(src: Path, dest: Path, key_path: Path) -> dict[str, str]:
    """Copy `src` to `dest` with real participant ids replaced; write the key; return {id: pseudonym}."""
    src, dest, key_path = Path(src), Path(dest), Path(key_path)
    if not (src / "trials.jsonl").is_file():
        raise ValueError(f"{src} is not a study folder (no trials.jsonl)")
    if dest.exists():
        raise ValueError(f"{dest} exists; choose a new folder (nothing is overwritten)")
    for folder in (src, dest):
        if key_path.resolve().is_relative_to(folder.resolve()):
            raise ValueError("the key must lie outside the study folders")
    rows = [json.loads(x) for x in (src / "trials.jsonl").read_text().splitlines() if x.strip()]
    likert_path = src / "likert.jsonl"
    likert = [json.loads(x) for x in likert_path.read_text().splitlines() if x.strip()] \
        if likert_path.exists() else []
    mapping: dict[str, str] = {}
    for who in [r["participant"] for r in rows] + [r["participant"] for r in likert]:
        if who not in mapping:
            mapping[who] = who if who.startswith("sim:") else \
                f"P{sum(not w.startswith('sim:') for w in mapping) + 1:02d}"
    (dest / "trials").mkdir(parents=True)
    with open(dest / "trials.jsonl", "w") as f:
        for r in rows:
            new = dict(r, participant=mapping[r["participant"]])
            new["key"] = "|".join([new["participant"], *r["key"].split("|")[1:]])
            new["file"] = file_stem(new["key"])
            npz = src / "trials" / f"{r['file']}.npz"
            if npz.is_file():
                shutil.copyfile(npz, dest / "trials" / f"{new['file']}.npz")
            f.write(json.dumps(new, sort_keys=True) + "\n")
    if likert:
        with open(dest / "likert.jsonl", "w") as f:
            for r in likert:
                f.write(json.dumps(dict(r, participant=mapping[r["participant"]]), sort_keys=True) + "\n")
    meta_path = src / "study.json"
    if meta_path.is_file():
        meta = json.loads(meta_path.read_text())
        meta["protocol"] = Path(str(meta.get("protocol", ""))).name
        (dest / "study.json").write_text(json.dumps(meta, indent=1) + "\n")
    key_path.parent.mkdir(parents=True, exist_ok=True)
    with open(key_path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["pseudonym", "participant"])
        for who, alias in mapping.items():
            if alias != who:
                w.writerow([alias, who])
    return mapping


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", type=Path, required=True, help="the study folder (--out of the study)")
    ap.add_argument("--dest", type=Path, required=True, help="the shareable copy (must not exist)")
    ap.add_argument("--key", type=Path, required=True, help="where the pseudonym key goes (CSV)")
    a = ap.parse_args(argv)
    try:
        mapping = anonymise(a.src, a.dest, a.key)
    except ValueError as e:
        print(f"anonymise: {e}")
        return 2
    real = sum(alias != who for who, alias in mapping.items())
    print(f"{a.dest}: {real} participants pseudonymised, key in {a.key}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
