"""The protocol file: read as a catalogue is (hostile files get one clear line, never a traceback, a
hang or the file's content), checked by its schema with file:line, and its test set kept apart from
the development files it names (issue 32 item 10, issue 33)."""
from __future__ import annotations

import os
import subprocess
import sys
import threading

import pytest
from vla_study.protocol import PAPER, ProtocolError, load_protocol
from vla_study.runner import reused_seeds, run_study, trial_plan

from vla_study import cli

SECRET = "hunter2-do-not-echo"
SMALL = ("participants: sim:2\nstrategies: [latent-YOLO]\nsettings:\n  base: bread/push_east\n"
         "trials: 1\npractice: {trials: 0, reset_seed: 7}\n")


def _run_cli(argv, capsys) -> tuple[int, str]:
    rc = cli.main(argv)
    cap = capsys.readouterr()
    return rc, cap.err


def _hostile(kind: str, tmp_path):
    f = tmp_path / f"{kind}.yaml"
    if kind == "alias_bomb":
        def alias(i: int) -> str:
            a, b = chr(97 + i), chr(98 + i)
            return f"{b}: &{b} [*{a}, *{a}, *{a}, *{a}, *{a}, *{a}, *{a}, *{a}, *{a}]"

        lines = ['a: &a ["' + SECRET + '"]'] + [alias(i) for i in range(9)]
        f.write_text("\n".join(lines) + "\n")
    elif kind == "dev_zero":
        return "/dev/zero"
    elif kind == "dev_urandom":
        return "/dev/urandom"
    elif kind == "fifo":
        os.mkfifo(f)
    elif kind == "not_utf8":
        f.write_bytes(b"participants: sim:2\nstudy: " + SECRET.encode() + b"\xff\xfe\n")
    elif kind == "deep":
        f.write_text("participants: " + "[" * 5000 + SECRET + "]" * 5000 + "\n")
    elif kind == "huge":
        f.write_text("study: " + SECRET + "x" * (400 * 1024) + "\n")
    elif kind == "folder":
        f.mkdir()
    elif kind == "huge_int":
        f.write_text("participants: sim:2\ntrials: " + "9" * 5000 + "\n")
    return str(f)


HOSTILE = {"alias_bomb": "anchors and aliases", "dev_zero": "not a regular file",
           "dev_urandom": "not a regular file", "fifo": "not a regular file", "not_utf8": "not UTF-8",
           "deep": "nested deeper than", "huge": "more than", "folder": "not a regular file",
           "huge_int": "a value cannot be read"}


@pytest.mark.timeout(60)
@pytest.mark.parametrize("kind", sorted(HOSTILE))
def test_a_hostile_protocol_file_gets_one_clear_line(kind, tmp_path, capsys):
    """Each is refused at once with one line naming the file (no traceback, no MemoryError, no hang on
    a FIFO nobody writes to), and nothing of the file's content is quoted."""
    path = _hostile(kind, tmp_path)
    done: list[tuple[int, str]] = []
    argv = ["--protocol", path, "--check"]
    worker = threading.Thread(target=lambda: done.append(_run_cli(argv, capsys)), daemon=True)
    worker.start()
    worker.join(30)
    assert done, f"{kind}: no answer within 30 s"
    rc, err = done[0]
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"protocol refused: {path}:"), err
    assert HOSTILE[kind] in lines[0], err
    assert SECRET not in err and "Traceback" not in err and "99999" not in err


def test_out_naming_a_file_is_one_clear_line(tmp_path):
    """--out naming a file (or a folder under one) is refused in one line, through the command as a user
    runs it: no traceback."""
    f = tmp_path / "p.yaml"
    f.write_text(SMALL)
    afile = tmp_path / "a_file"
    afile.write_text("not a folder\n")
    for out in (afile, afile / "below"):
        res = subprocess.run([sys.executable, "-m", "vla_study.cli", "--protocol", str(f), "--out", str(out),
                              "--analyse-only"], capture_output=True, text=True, timeout=300)
        assert res.returncode == 2, res.stdout + res.stderr
        assert "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1, res.stderr
        assert f"--out {out}: {afile} is not a directory" in res.stderr
    with pytest.raises(SystemExit, match="a study folder is a directory"):
        run_study(load_protocol(f), afile / "below", backend=object())


def test_schema_errors_say_file_line_and_the_key(tmp_path):
    """Every problem at once, each at its own line, with the key's path; numbers too large for a float,
    booleans for numbers and NaN are refused by name."""
    f = tmp_path / "bad.yaml"
    f.write_text("participants: sim:2\n"                      # 1
                 "strategies: [latent-YOLO]\n"                # 2
                 "settings:\n"                                # 3
                 "  base: [bread/push_east]\n"                # 4
                 "time_limit: 1e400\n"                        # 5
                 "rate: .nan\n"                               # 6
                 "trials: true\n"                             # 7
                 "practice: {trials: 1, reset_seed: 7, extra: 1}\n"  # 8
                 "seeds: {layouts: -1}\n"                     # 9
                 "end_effector_axes: [x, y, yaw]\n"           # 10
                 "role: maybe\n")                             # 11
    with pytest.raises(ProtocolError) as e:
        load_protocol(f)
    msgs = e.value.errors
    for line, word in ((5, "time_limit"), (6, "rate"), (7, "trials"), (8, "extra"), (9, "seeds.layouts"),
                       (10, "including x, y and z"), (11, "role")):
        assert any(m.startswith(f"{f}:{line}: ") and word in m for m in msgs), (line, word, msgs)
    assert all(m.count("\n") == 0 for m in msgs)


def test_a_test_protocol_that_reuses_a_development_files_seeds_is_refused(tmp_path, capsys):
    """Issue 33: the protocol says which trials are development and which the test; the runner (and
    --check) refuses a test protocol whose test trials reuse the layouts or operator seeds of a
    development file it names, before anything is made. The shipped protocols are disjoint."""
    dev = tmp_path / "dev.yaml"
    dev.write_text("role: development\n" + SMALL)
    test = tmp_path / "test.yaml"
    test.write_text(SMALL.replace("trials: 1\n", "trials: 2\n") + "development: [dev.yaml]\n")
    p = load_protocol(test)
    why = reused_seeds(p)
    assert len(why) == 1 and "dev.yaml" in why[0]
    assert why[0].startswith(f"{test}:7: 2 of the 4 test trials reuse"), why
    out = tmp_path / "never"
    with pytest.raises(SystemExit, match="reuse the layouts or operator seeds"):
        run_study(p, out, backend=object())
    assert not out.exists()
    rc, err = _run_cli(["--protocol", str(test), "--check"], capsys)
    assert rc == 2 and "reuse the layouts" in err
    # its own seeds: accepted, and no test trial shares a layout or an operator seed with development
    test.write_text(test.read_text() + "seeds: {layouts: 650000, operators: test}\n")
    assert reused_seeds(load_protocol(test)) == []
    # a development file must say so; only a test protocol names development files
    dev.write_text(SMALL)
    with pytest.raises(ProtocolError, match=r"test.yaml:7: development file 'dev.yaml': .*role is test"):
        load_protocol(test)
    for name in ("paper.yaml", "shipped.yaml", "base_three.yaml"):
        shipped = load_protocol(PAPER.with_name(name))
        assert shipped.role == "test" and len(shipped.development) == 2, name
        assert reused_seeds(shipped) == [], name


def test_the_old_seeds_of_the_paper_protocol_reused_its_development_layouts(tmp_path):
    """What the issue found: with the first runs' seeds, 36 of the 126 latent-YOLO test trials of the
    paper protocol were on the layouts the latent policy was revised on (45 with the operator seeds)."""
    text = PAPER.read_text().replace("seeds: {layouts: 600000, operators: test}\n", "")
    dev = PAPER.with_name("development")
    text = text.replace("development/", f"{dev}/")
    old = tmp_path / "paper_old_seeds.yaml"
    old.write_text(text)
    p = load_protocol(old)
    latent_dev = load_protocol(p.development[0])
    layouts = {(t.task, t.layout_seed) for t in trial_plan(latent_dev)}
    mine = [t for t in trial_plan(p) if t.phase == "test" and t.strategy == "latent-YOLO"]
    assert len(mine) == 126 and sum((t.task, t.layout_seed) in layouts for t in mine) == 36
    assert any("117 of the 378 test trials" in m for m in reused_seeds(p))
