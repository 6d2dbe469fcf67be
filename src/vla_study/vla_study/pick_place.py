"""The pick-and-place table: one row per condition (latent alone, end-effector alone, hybrid control, and
assisted ones: latent with assistance high),
on the same test layouts, from a study folder's rows (protocols/pick_place.yaml's study).

    python -m vla_study.pick_place --out out/pick_place     # writes out/pick_place/pick_place.md
    python -m vla_study.pick_place --out out/assisted --also docs/results/pick-place/trials.jsonl

Success, the placement error (the object's distance from its place at the end, every trial), the time
(a failure counts the time limit, outcome.py) and the hand's effort. Every row is the simulated
participants' (hand_participant.py), labelled so. Only layouts run in every condition count (a study
stopped early leaves some layouts in one condition only: the table says how many rows it left out).
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

ORDER = ("latent alone", "end-effector alone", "hybrid control")   # then assisted ones, as they come


def conditions(rows: list[dict]) -> list[str]:
    """The conditions present: ORDER's, then the others (`latent with assistance high`) in row order."""
    present = list(dict.fromkeys(r["condition"] for r in rows))
    return [c for c in ORDER if c in present] + [c for c in present if c not in ORDER]


def test_rows(path: Path) -> list[dict]:
    """The test trials of a pick-and-place study's trials.jsonl (rows with a `condition`)."""
    rows = [json.loads(x) for x in path.read_text().splitlines() if x.strip()]
    return [r for r in rows if r.get("phase") == "test" and r.get("condition")]


def _median(values: list[float]) -> float:
    return statistics.median(values) if values else float("nan")


def _s(value: float) -> str:
    """A median for the table: one decimal, a dash where there was nothing to take it of."""
    return "–" if value != value else f"{value:.1f}"


def shared_layouts(rows: list[dict]) -> tuple[list[dict], int]:
    """The rows on layouts (participant, layout seed) that every condition present ran; how many left out."""
    sets = [{(r["participant"], r["layout_seed"]) for r in rows if r["condition"] == c}
            for c in conditions(rows)]
    shared = set.intersection(*sets) if sets else set()
    kept = [r for r in rows if (r["participant"], r["layout_seed"]) in shared]
    return kept, len(rows) - len(kept)


def table(rows: list[dict]) -> str:
    """Markdown: per condition, success, placement error, time and the hand's presses."""
    rows, left_out = shared_layouts(rows)
    layouts = {c: [r for r in rows if r["condition"] == c] for c in conditions(rows)}
    n = len(next(iter(layouts.values()), []))
    limit = rows[0]["time_limit_s"] if rows else float("nan")
    plural = "s" if left_out > 1 else ""
    dropped = f" ({left_out} row{plural} on layouts not run in every condition left out)" if left_out else ""
    lines = [f"Simulated participants (vla_study.hand_participant), {n} test layouts per condition, the same "
             f"layouts in each{dropped}; through the graph in lockstep. A failure's time is the limit "
             f"({limit:g} s).",
             "", "| condition | success | placement error, median (cm) | time, median (s) | "
             "time of successes, median (s) | grasp presses, median | failed grasps | mode switches "
             "(latent/end effector), median | thrown |", "|---|---|---|---|---|---|---|---|---|"]
    for c, mine in layouts.items():
        ok = [r for r in mine if r["success"]]
        err = _median([100 * r["placement_error_m"] for r in mine])
        lines.append(
            f"| {c} | {len(ok)}/{len(mine)} ({len(ok) / len(mine):.2f}) | {err:.1f} | "
            f"{_median([r['time_s'] for r in mine]):.1f} | {_s(_median([r['time_s'] for r in ok]))} | "
            f"{_median([r['grasp_presses'] for r in mine]):g} | {sum(r['failed_grasps'] for r in mine)} | "
            f"{_median([r['control_switches'] for r in mine]):g} | {sum(bool(r['thrown']) for r in mine)} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="the study folder (its trials.jsonl)")
    ap.add_argument("--also", type=Path, action="append", default=[], metavar="TRIALS.jsonl",
                    help="rows of the other conditions from another run of the protocol's layouts (a "
                         "condition run alone with --only); a condition in both is taken from --out")
    args = ap.parse_args(argv)
    rows_path = args.out / "trials.jsonl"
    for path in (rows_path, *args.also):
        if not path.is_file():
            print(f"{path}: no rows", file=sys.stderr)
            return 2
    rows = test_rows(rows_path)
    mine = {r["condition"] for r in rows}
    for path in args.also:
        rows += [r for r in test_rows(path) if r["condition"] not in mine]
    text = table(rows)
    (args.out / "pick_place.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
