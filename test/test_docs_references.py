"""A reader of the repository alone finds everything its documents name (issue 33): no document outside
it (the task's notes, numbered contracts), no machine-local path in the history, and every relative
Markdown link resolves."""
import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TEXT = (".md", ".py", ".sh", ".yaml", ".toml", ".txt", ".cfg", ".xml")


def tracked(suffixes=TEXT) -> list[Path]:
    out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    return [ROOT / f for f in out.splitlines() if f.endswith(suffixes) and (ROOT / f).is_file()]


def test_no_document_outside_the_repository_is_named():
    named = re.compile(r"FACTS\.md|\bcontract [0-9]+\b")
    found = [f"{f.relative_to(ROOT)}:{n}" for f in tracked() if f.name != Path(__file__).name
             for n, line in enumerate(f.read_text(errors="replace").splitlines(), 1) if named.search(line)]
    assert not found, found


def test_the_history_keeps_no_machine_local_paths():
    local = re.compile(r"(?<![\w.])/(tmp|root|home|work)/")
    history = [f for f in tracked((".md",)) if "history" in f.parts or f.name == "history.md"]
    found = [f"{f.relative_to(ROOT)}:{n}" for f in history
             for n, line in enumerate(f.read_text().splitlines(), 1) if local.search(line)]
    assert not found, found


def test_relative_markdown_links_resolve():
    link = re.compile(r"\]\(([^)\s#]+)(?:#[^)]*)?\)")
    broken = []
    for f in tracked((".md",)):
        for target in link.findall(f.read_text()):
            if re.match(r"^[a-z]+:", target):
                continue
            if not (f.parent / target).exists():
                broken.append(f"{f.relative_to(ROOT)} -> {target}")
    assert not broken, broken
