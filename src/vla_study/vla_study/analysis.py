"""The study's figures, tables and paired statistics from trials.jsonl (test trials only).

Figure 4 (left): success rate per strategy and setting, mean over participants with the standard
error across participants. Figure 3: top-down end-effector paths per strategy. Tables: success, time,
smoothness (SPARC, LDLJ), path length, inputs, mode switches and their share of execution time.
Paired statistics: per participant the strategy's mean over settings, differences between strategies
with an exact sign-flip permutation test (no distribution assumed; n = 9 gives 512 sign patterns).
Every figure and table says "simulated participants" when the study's participants are simulated.
"""
from __future__ import annotations

import itertools
import json
import math
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def load_rows(out: Path) -> list[dict]:
    p = Path(out) / "trials.jsonl"
    if not p.exists():
        return []
    return [json.loads(x) for x in p.read_text().splitlines() if x.strip()]


def mean_se(values) -> tuple[float, float, int]:
    v = np.asarray([x for x in values if x is not None and not (isinstance(x, float) and math.isnan(x))],
                   float)
    if len(v) == 0:
        return float("nan"), float("nan"), 0
    se = float(v.std(ddof=1) / math.sqrt(len(v))) if len(v) > 1 else float("nan")
    return float(v.mean()), se, len(v)


def sign_flip_p(diffs) -> float:
    """Two-sided exact p of the mean paired difference under random sign flips (exhaustive to n=16)."""
    d = np.asarray(diffs, float)
    d = d[~np.isnan(d)]
    n = len(d)
    if n == 0 or n > 16:
        return float("nan")
    obs = abs(d.mean())
    count = 0
    for signs in itertools.product((1.0, -1.0), repeat=n):
        if abs((d * np.asarray(signs)).mean()) >= obs - 1e-12:
            count += 1
    return count / 2 ** n


def per_participant(rows, metric, strategy, setting=None) -> dict[str, float]:
    acc: dict[str, list] = defaultdict(list)
    for r in rows:
        if r["strategy"] == strategy and (setting is None or r["setting"] == setting):
            v = r.get(metric)
            if v is not None:
                acc[r["participant"]].append(float(v))
    return {p: float(np.mean(v)) for p, v in acc.items() if v}


def _label(simulated: bool) -> str:
    return "simulated participants" if simulated else "participants"


def analyse(out: Path, figures: Path) -> list[str]:
    """Write figure4_success.png, figure3_paths.png and study_tables.md; return the lines printed."""
    out, figures = Path(out), Path(figures)
    rows = [r for r in load_rows(out) if r.get("phase") == "test"]
    if not rows:
        return [f"[study] no test trials in {out} yet"]
    figures.mkdir(parents=True, exist_ok=True)
    simulated = all(r.get("simulated", True) for r in rows)
    who = _label(simulated)
    strategies = list(dict.fromkeys(r["strategy"] for r in rows))
    settings = list(dict.fromkeys(r["setting"] for r in rows))
    participants = sorted({r["participant"] for r in rows}, key=lambda s: (len(s), s))
    lines = [f"# User study ({who}): {len(rows)} test trials, {len(participants)} participants, "
             f"strategies {', '.join(strategies)}", ""]
    if simulated:
        lines += ["All numbers below come from **simulated participants** (the human-like operator model "
                  "of vla_study.participant), not from people.", ""]
    ways = {"graph": "through the launched graph (the stick published as Joy, a bag per trial)",
            "physics": "on the physics backend (the graph's computations in one process)"}
    backends = sorted({r.get("backend", "physics") for r in rows})
    lines += ["Trials ran " + " and ".join(ways.get(b, b) for b in backends) + ".", ""]
    if any(r.get("robot") == "real" for r in rows):
        lines += ["On the real robot (`robot: real`): the experimenter placed each object at its start "
                  "point and scored success (and, where measured, the object's displacement); time, path, "
                  "smoothness, inputs and mode switches were measured from joint_states.", ""]

    # ---- Figure 4: success per strategy and setting
    fig, ax = plt.subplots(figsize=(7, 3.6))
    width = 0.8 / max(1, len(strategies))
    x = np.arange(len(settings))
    for i, s in enumerate(strategies):
        ms = [mean_se(per_participant(rows, "success", s, st).values()) for st in settings]
        ax.bar(x + (i - (len(strategies) - 1) / 2) * width, [m[0] for m in ms], width,
               yerr=[0 if math.isnan(m[1]) else m[1] for m in ms], capsize=3, label=s)
    ax.set_xticks(x, settings)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("success rate")
    ax.set_title(f"Figure 4 (left), {who}: success, SE across participants (n={len(participants)})",
                 fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(figures / "figure4_success.png", dpi=120)
    plt.close(fig)

    # ---- Figure 3: top-down paths per strategy
    show = next((s for s in ("Near", "Seen", "Far") if s in settings), settings[0])
    fig, axes = plt.subplots(1, len(strategies), figsize=(3.6 * len(strategies), 3.6), squeeze=False)
    for ax, s in zip(axes[0], strategies):
        for r in rows:
            if r["strategy"] != s or r["setting"] != show:
                continue
            f = out / "trials" / f"{r['file']}.npz"
            if not f.exists():
                continue
            with np.load(f, allow_pickle=False) as d:
                tcp = d["tcp"]
            if len(tcp):
                ax.plot(tcp[:, 1], tcp[:, 0], lw=0.8, color="tab:green" if r["success"] else "tab:red",
                        alpha=0.8)
                o = r["object_start"]
                ax.plot(o["y"], o["x"], "ks", ms=4)
        ax.set_title(f"{s} ({show})", fontsize=9)
        ax.set_xlabel("y (m)")
        ax.set_ylabel("x (m)")
        ax.invert_xaxis()
        ax.set_aspect("equal", adjustable="datalim")
    fig.suptitle(f"Figure 3, {who}: top-down end-effector paths (green: success, red: failure; "
                 "squares: object starts)", fontsize=9)
    fig.tight_layout()
    fig.savefig(figures / "figure3_paths.png", dpi=120)
    plt.close(fig)

    # ---- tables
    def cell(metric, s, st=None, fmt="{:.2f}"):
        m, se, n = mean_se(per_participant(rows, metric, s, st).values())
        if n == 0 or math.isnan(m):
            return "–"
        return fmt.format(m) + ("" if math.isnan(se) else " ± " + fmt.format(se))

    lines += [f"## Success rate per setting ({who}; mean ± SE across participants)", "",
              "| strategy | " + " | ".join(settings) + " | all |", "|---" * (len(settings) + 2) + "|"]
    for s in strategies:
        lines.append(f"| {s} | " + " | ".join(cell("success", s, st) for st in settings)
                     + f" | {cell('success', s)} |")
    lines += ["", f"## Time, smoothness and effort ({who}; mean ± SE across participants, all settings)", "",
              "| strategy | time (s) | SPARC | LDLJ | path (m) | inputs | mode switches | switching share |",
              "|---|---|---|---|---|---|---|---|"]
    for s in strategies:
        sr = [r for r in rows if r["strategy"] == s]
        # a person's switching time is not seen (the row's mode_switch_s is None): no share for them
        timed = [r for r in sr if r.get("mode_switch_s") is not None]
        switching = sum(r["mode_switch_s"] for r in timed)
        share = f"{100 * switching / max(1e-9, sum(r['duration_s'] for r in timed)):.1f} %" if timed else "–"
        lines.append(f"| {s} | {cell('time_s', s)} | {cell('sparc', s)} | {cell('ldlj', s)} | "
                     f"{cell('path_length_m', s)} | {cell('n_inputs', s, fmt='{:.1f}')} | "
                     f"{cell('mode_switches', s, fmt='{:.1f}')} | {share} |")
    lines += ["", "time: to success (the time limit for a failure). SPARC, LDLJ: closer to 0 is smoother. "
              "Switching share: mode-switch time (decisions and presses) over execution time; Herlant et "
              "al. 2016 measured 17.4 %.", ""]
    # ---- paired statistics
    if len(strategies) >= 2:
        lines += [f"## Paired statistics ({who}; per participant the mean over settings; exact sign-flip "
                  "test)", "", "| comparison | metric | mean difference | n | p |", "|---|---|---|---|---|"]
        for a, b in itertools.combinations(strategies, 2):
            for metric in ("success", "time_s", "sparc", "ldlj", "path_length_m"):
                pa, pb = per_participant(rows, metric, a), per_participant(rows, metric, b)
                common = sorted(set(pa) & set(pb))
                diffs = [pa[p] - pb[p] for p in common]
                if not diffs:
                    continue
                lines.append(f"| {a} − {b} | {metric} | {np.mean(diffs):+.3f} | {len(diffs)} | "
                             f"{sign_flip_p(diffs):.3f} |")
        lines.append("")
    lines += [f"Figures: figure4_success.png, figure3_paths.png ({who}). Wall time per trial: median "
              f"{np.median([r.get('wall_s', 0) for r in rows]):.1f} s."]
    (figures / "study_tables.md").write_text("\n".join(lines) + "\n")
    return lines


def sensitivity_table(path: Path) -> list[str]:
    """sensitivity.jsonl -> a markdown table: success per (delay, noise) for each strategy."""
    rows = [json.loads(x) for x in Path(path).read_text().splitlines() if x.strip()]
    strategies = list(dict.fromkeys(r["strategy"] for r in rows))
    cells = sorted({(r["reaction_s"], r["motor_k"]) for r in rows})
    lines = ["| reaction delay (s) | stick noise k | " + " | ".join(strategies) + " |",
             "|---|---|" + "---|" * len(strategies)]
    for d, k in cells:
        vals = []
        for s in strategies:
            ok = [r["success"] for r in rows
                  if r["strategy"] == s and r["reaction_s"] == d and r["motor_k"] == k]
            vals.append(f"{sum(ok)}/{len(ok)}" if ok else "–")
        lines.append(f"| {d:g} | {k:g} | " + " | ".join(vals) + " |")
    return lines
