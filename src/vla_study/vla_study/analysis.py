"""The study's figures, tables and paired statistics from trials.jsonl (test trials only).

Per setting first, then the equal-weight aggregate: every table gives each setting (base, Seen, Near,
Far) on its own, and "settings, equal weight" is, per participant, the mean of their per-setting means,
then the mean ± SE across participants; each setting counts once however many trials it has (base has
four tasks, the few-shot settings one each), as Figure 4 plots them. A failure's time is the time limit
and a thrown object (outcome.py) is flagged and counted apart. Paired statistics compare two
strategies per participant on that equal-weight mean, with an exact sign-flip permutation test (no
distribution assumed; n = 9 gives 512 sign patterns), and per setting.
Every figure and table says "simulated participants" when the study's participants are simulated.
"""
from __future__ import annotations

import itertools
import json
import math
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from vla_study.outcome import THROWN_M, thrown, trial_time  # noqa: E402
from vla_study.protocol_schema import OFF, assistance_of, strategy_label  # noqa: E402

EQUAL = "settings, equal weight"
SHARE = "Switching share: mode-switch time (decisions and presses) over execution time. "
HERLANT = {True: "The simulated participants' button timing was calibrated on development trials "
                 "towards Herlant et al. 2016's 17.4 % (protocols/development/ee_calibration.yaml), so the "
                 "share is a calibration, not a finding.",
           False: "Herlant et al. 2016 measured 17.4 % with a joystick."}


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


def value(row: dict, metric: str, limit: float | None):
    """A row's metric as the tables count it: `time_s` of a failure is the time limit (the row's own
    `time_limit_s`, or `limit` for rows made before it was kept); `thrown` from the displacement."""
    if metric == "time_s":
        lim = row.get("time_limit_s", limit)
        return trial_time(row["success"], row.get("time_s"), lim) if lim is not None else row.get("time_s")
    if metric == "thrown":
        return row.get("thrown", thrown(row.get("object_displacement_m")))
    return row.get(metric)


def per_participant(rows, metric, strategy, setting=None, limit=None) -> dict[str, float]:
    """Per participant, the mean of `metric` over their trials of `strategy` in `setting`; with
    `setting` None, the mean of their per-setting means (every setting weighs the same)."""
    if setting is None:
        by: dict[str, list[float]] = defaultdict(list)
        for st in dict.fromkeys(r["setting"] for r in rows):
            for who, v in per_participant(rows, metric, strategy, st, limit).items():
                by[who].append(v)
        return {who: float(np.mean(v)) for who, v in by.items()}
    acc: dict[str, list] = defaultdict(list)
    for r in rows:
        if r["strategy"] == strategy and r["setting"] == setting:
            v = value(r, metric, limit)
            if v is not None:
                acc[r["participant"]].append(float(v))
    return {p: float(np.mean(v)) for p, v in acc.items() if v}


def _label(simulated: bool) -> str:
    return "simulated participants" if simulated else "participants"


@dataclass
class Study:
    """The test rows of a study folder and what the tables are made over."""

    rows: list[dict]
    strategies: list[str]
    settings: list[str]
    participants: list[str]
    who: str
    limit: float | None

    @classmethod
    def of(cls, rows: list[dict], limit: float | None, strategies: Sequence[str] = (),
           settings: Sequence[str] = ()) -> Study:
        """`strategies`, `settings`: the protocol's order for the tables (the rows' order otherwise:
        that of the units' completion, which a sweep decides)."""
        simulated = all(r.get("simulated", True) for r in rows)
        return cls(rows, _ordered((r["strategy"] for r in rows), strategies),
                   _ordered((r["setting"] for r in rows), settings),
                   sorted({r["participant"] for r in rows}, key=lambda s: (len(s), s)), _label(simulated),
                   limit)

    def cell(self, metric, s, st=None, fmt="{:.2f}") -> str:
        m, se, n = mean_se(per_participant(self.rows, metric, s, st, self.limit).values())
        if n == 0 or math.isnan(m):
            return "–"
        return fmt.format(m) + ("" if math.isnan(se) else " ± " + fmt.format(se))

    def count(self, s, st, metric="success") -> str:
        got = [bool(value(r, metric, self.limit)) for r in self.rows
               if r["strategy"] == s and r["setting"] == st]
        return f"{sum(got)}/{len(got)}" if got else "–"


def _ordered(names, first: Sequence[str]) -> list[str]:
    """The distinct `names`, those in `first` in its order, then the others as they came."""
    seen = list(dict.fromkeys(names))
    return [x for x in first if x in seen] + [x for x in seen if x not in first]


def analyse(out: Path, figures: Path, time_limit: float | None = None, strategies: Sequence[str] = (),
            settings: Sequence[str] = ()) -> list[str]:
    """Write figure4_success.png, figure3_paths.png and study_tables.md; return the lines printed.
    `time_limit`: the protocol's, for rows made before each row kept its own; `strategies`,
    `settings`: the protocol's order for the tables and figures."""
    out, figures = Path(out), Path(figures)
    rows = [r for r in load_rows(out) if r.get("phase") == "test"]
    if not rows:
        return [f"[study] no test trials in {out} yet"]
    figures.mkdir(parents=True, exist_ok=True)
    st = Study.of(rows, time_limit, strategies, settings)
    lines = _header(st)
    _figure4(st, figures / "figure4_success.png")
    _figure3(st, out, figures / "figure3_paths.png")
    lines += _success_table(st) + _time_table(st) + _effort_table(st) + _thrown_table(st)
    lines += _paired(st)
    lines += [f"Figures: figure4_success.png, figure3_paths.png ({st.who}). Wall time per trial: median "
              f"{np.median([r.get('wall_s', 0) for r in rows]):.1f} s."]
    (figures / "study_tables.md").write_text("\n".join(lines) + "\n")
    return lines


def _header(st: Study) -> list[str]:
    rows = st.rows
    lines = [f"# User study ({st.who}): {len(rows)} test trials, {len(st.participants)} participants, "
             f"strategies {', '.join(map(strategy_label, st.strategies))}", ""]
    if st.who.startswith("simulated"):
        lines += ["All numbers below come from **simulated participants** (the human-like operator model "
                  "of vla_study.participant), not from people: they say what this operator model does with "
                  "each strategy, not what a person would.", ""]
    ways = {"graph": "through the launched graph (the stick published as Joy, a bag per trial)",
            "physics": "on the physics backend (the graph's computations copied into one process; gone "
                       "since issue 33: its numbers were not the graph's)"}
    backends = sorted({r.get("backend", "physics") for r in rows})
    lines += ["Trials ran " + " and ".join(ways.get(b, b) for b in backends) + ".", ""]
    assisted = [strategy_label(s) for s in st.strategies if assistance_of(s) != OFF]
    if assisted:
        lines += [f"Assisted conditions ({', '.join(assisted)}): the controller's assistance (goal inference "
                  "over the detected objects' tasks and a pull toward the inferred goal, "
                  "vla_latent_controller.assistance) at the level named, with the strategy's model; every "
                  "other condition has it off.", ""]
    rtf = [r["trial_rtf"] for r in rows if r.get("trial_rtf") is not None and not r.get("lockstep")]
    if rtf:
        lines += [f"{len(rtf)} trials ran the graph in real time, at {min(rtf):.2f}–{max(rtf):.2f} × real "
                  "time (the machine's load): their outcomes can change with the load.", ""]
    locked = sum(1 for r in rows if r.get("lockstep"))
    if locked:
        lines += [f"{locked} trials ran the graph in lockstep (the simulation waits for every node each "
                  "step): their outcomes are a function of their seeds and the code, whatever the load.", ""]
    if any(r.get("robot") == "real" for r in rows):
        lines += ["On the real robot (`robot: real`): the experimenter placed each object at its start "
                  "point and scored success (and, where measured, the object's displacement); time, path, "
                  "smoothness, inputs and mode switches were measured from joint_states.", ""]
    return lines


def _settings_table(st: Study, title: str, metric: str, fmt: str, counts: bool) -> list[str]:
    lines = [title, "", "| strategy | " + " | ".join(st.settings) + f" | {EQUAL} |",
             "|---" * (len(st.settings) + 2) + "|"]
    for s in st.strategies:
        cells = [f"{st.count(s, x)} ({st.cell(metric, s, x, fmt)})" if counts else st.cell(metric, s, x, fmt)
                 for x in st.settings]
        lines.append(f"| {strategy_label(s)} | " + " | ".join(cells)
                     + f" | {st.cell(metric, s, None, fmt)} |")
    return lines + [""]


def _success_table(st: Study) -> list[str]:
    return _settings_table(st, f"## Success per setting ({st.who}; successes/trials, and mean ± SE across "
                           f"participants), then the settings weighed equally", "success", "{:.2f}", True)


def _time_table(st: Study) -> list[str]:
    lim = sorted({r.get("time_limit_s", st.limit) for r in st.rows} - {None})
    said = f" ({', '.join(f'{x:g}' for x in lim)} s)" if lim else ""
    return _settings_table(st, f"## Time per setting ({st.who}; s, mean ± SE across participants; a failure "
                           f"counts the time limit{said})", "time_s", "{:.1f}", False)


def _effort_table(st: Study) -> list[str]:
    lines = [f"## Smoothness and effort ({st.who}; mean ± SE across participants, {EQUAL})", "",
             "| strategy | SPARC | LDLJ | path (m) | inputs | mode switches | switching share |",
             "|---|---|---|---|---|---|---|"]
    for s in st.strategies:
        share = _switching_share(st, s)
        cells = [st.cell(m, s) for m in ("sparc", "ldlj", "path_length_m")]
        cells += [st.cell(m, s, fmt="{:.1f}") for m in ("n_inputs", "mode_switches")]
        cells.append("–" if share is None else f"{100 * share:.1f} %")
        lines.append(f"| {strategy_label(s)} | " + " | ".join(cells) + " |")
    simulated = st.who.startswith("simulated")
    return lines + ["", "SPARC, LDLJ: closer to 0 is smoother. " + SHARE + HERLANT[simulated], ""]


def _switching_share(st: Study, s: str) -> float | None:
    """Mode-switch time over execution time per setting, then the mean over settings; None when no
    switching time is seen (a person's is not: the row's mode_switch_s is None)."""
    shares = []
    for x in st.settings:
        timed = [r for r in st.rows
                 if r["strategy"] == s and r["setting"] == x and r.get("mode_switch_s") is not None]
        if timed:
            switching = sum(r["mode_switch_s"] for r in timed)
            shares.append(switching / max(1e-9, sum(r["duration_s"] for r in timed)))
    return float(np.mean(shares)) if shares else None


def _thrown_table(st: Study) -> list[str]:
    lines = [f"## Thrown objects ({st.who}; the object ended {THROWN_M:g} m or more from its start: flung, "
             "not pushed; each is also a failure above)", "",
             "| strategy | " + " | ".join(st.settings) + " |", "|---" * (len(st.settings) + 1) + "|"]
    for s in st.strategies:
        lines.append(f"| {strategy_label(s)} | "
                     + " | ".join(st.count(s, x, "thrown") for x in st.settings) + " |")
    flung = [r for r in st.rows if value(r, "thrown", st.limit)]
    lines += [""] + [f"- {r['key']}: {r['object_displacement_m']:.2f} m" for r in flung]
    return lines + ([""] if flung else [])


def _paired(st: Study) -> list[str]:
    if len(st.strategies) < 2:
        return []
    lines = [f"## Paired statistics ({st.who}; per participant, exact sign-flip test)", "",
             "Per setting (success), then on the per-participant mean over the settings weighed equally.", "",
             "| comparison | setting | metric | mean difference | n | p |", "|---|---|---|---|---|---|"]
    for a, b in itertools.combinations(st.strategies, 2):
        for x, metric in [*((x, "success") for x in st.settings),
                          *((None, m) for m in ("success", "time_s", "sparc", "ldlj", "path_length_m"))]:
            pa = per_participant(st.rows, metric, a, x, st.limit)
            pb = per_participant(st.rows, metric, b, x, st.limit)
            diffs = [pa[p] - pb[p] for p in sorted(set(pa) & set(pb))]
            if diffs:
                lines.append(f"| {strategy_label(a)} − {strategy_label(b)} | {x or EQUAL} | {metric} | "
                             f"{np.mean(diffs):+.3f} | {len(diffs)} | {sign_flip_p(diffs):.3f} |")
    return lines + [""]


def _figure4(st: Study, path: Path) -> None:
    """Success per strategy and setting, then the equal-weight aggregate; SE across participants."""
    fig, ax = plt.subplots(figsize=(7.5, 3.6))
    groups = [*st.settings, "equal\nweight"]
    width = 0.8 / max(1, len(st.strategies))
    x = np.arange(len(groups))
    for i, s in enumerate(st.strategies):
        ms = [mean_se(per_participant(st.rows, "success", s, g, st.limit).values()) for g in st.settings]
        ms.append(mean_se(per_participant(st.rows, "success", s, None, st.limit).values()))
        ax.bar(x + (i - (len(st.strategies) - 1) / 2) * width, [m[0] for m in ms], width,
               yerr=[0 if math.isnan(m[1]) else m[1] for m in ms], capsize=3, label=strategy_label(s))
    ax.set_xticks(x, groups)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("success rate")
    ax.set_title(f"Figure 4 (left), {st.who}: success per setting, then the settings weighed equally; "
                 f"SE across participants (n={len(st.participants)})", fontsize=8)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _figure3(st: Study, out: Path, path: Path) -> None:
    """Top-down TCP paths per strategy on one few-shot setting (the trials' .npz files; none: no paths)."""
    show = next((s for s in ("Near", "Seen", "Far") if s in st.settings), st.settings[0])
    fig, axes = plt.subplots(1, len(st.strategies), figsize=(3.6 * len(st.strategies), 3.6), squeeze=False)
    for ax, s in zip(axes[0], st.strategies):
        for r in (r for r in st.rows if r["strategy"] == s and r["setting"] == show):
            f = out / "trials" / f"{r['file']}.npz"
            if not f.exists():
                continue
            with np.load(f, allow_pickle=False) as d:
                tcp = d["tcp"]
            if len(tcp):
                colour = "tab:green" if r["success"] else "tab:red"
                ax.plot(tcp[:, 1], tcp[:, 0], lw=0.8, color=colour, alpha=0.8)
                ax.plot(r["object_start"]["y"], r["object_start"]["x"], "ks", ms=4)
        ax.set_title(f"{strategy_label(s)} ({show})", fontsize=9)
        ax.set_xlabel("y (m)")
        ax.set_ylabel("x (m)")
        ax.invert_xaxis()
        ax.set_aspect("equal", adjustable="datalim")
    fig.suptitle(f"Figure 3, {st.who}: top-down end-effector paths (green: success, red: failure; "
                 "squares: object starts)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
