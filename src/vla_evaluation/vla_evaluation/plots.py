"""PNG plots of evaluation results (matplotlib, Agg backend: no display needed).

- `plot_mean_sem`: a metric against a swept variable, one line per group, shaded standard error
  (the paper's Figure 2 style);
- `plot_ee_paths`: top-down view of end-effector paths on the table, drawn with north (+x) up and
  west (+y) to the left, as the compass directions of the tasks read.
"""
from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from vla_evaluation.metrics import mean_sem, summarize, write_csv, write_json  # noqa: E402

PALETTE = {"detector": "tab:blue", "localization": "tab:green", "end_to_end": "tab:red",
           "transfer": "tab:orange", "no_transfer": "tab:gray"}


def sweep_stats(rows: Sequence[Mapping], x: str, y: str, group: str) -> dict[str, tuple]:
    """{group: (xs, means, sems)} from flat rows (values may be strings, as read from CSV)."""
    acc: dict[str, dict[float, list[float]]] = {}
    for r in rows:
        try:
            xv, yv = float(r[x]), float(r[y])
        except (TypeError, ValueError, KeyError):
            continue
        acc.setdefault(str(r[group]), {}).setdefault(xv, []).append(yv)
    out = {}
    for g, by_x in acc.items():
        xs = sorted(by_x)
        stats = [mean_sem(by_x[v]) for v in xs]
        out[g] = (np.array(xs), np.array([s[0] for s in stats]), np.array([s[1] for s in stats]))
    return out


def plot_mean_sem(ax, rows: Sequence[Mapping], x: str, y: str, group: str,
                  labels: Mapping[str, str] | None = None) -> dict[str, tuple]:
    """Draw mean lines with standard-error bands on `ax`; returns the statistics drawn."""
    stats = sweep_stats(rows, x, y, group)
    for g, (xs, means, sems) in stats.items():
        color = PALETTE.get(g)
        ax.plot(xs, means, marker="o", ms=3, color=color, label=(labels or {}).get(g, g))
        ax.fill_between(xs, means - sems, means + sems, color=color, alpha=0.25, linewidth=0)
    ax.grid(alpha=0.3)
    return stats


def save_sweep_plot(rows: Sequence[Mapping], x: str, y: str, group: str, path: str | os.PathLike,
                    title: str = "", xlabel: str = "", ylabel: str = "",
                    labels: Mapping[str, str] | None = None) -> Path:
    fig, ax = plt.subplots(figsize=(5, 3.6), dpi=120)
    plot_mean_sem(ax, rows, x, y, group, labels)
    ax.set_title(title)
    ax.set_xlabel(xlabel or x)
    ax.set_ylabel(ylabel or y)
    ax.legend(fontsize=8)
    return _save(fig, path)


def save_panel_plot(panels: Sequence[tuple[str, Sequence[Mapping]]], x: str, y: str, group: str,
                    path: str | os.PathLike, xlabel: str = "", ylabel: str = "",
                    labels: Mapping[str, str] | None = None) -> Path:
    """Several sweeps side by side sharing y (e.g. Seen / Near / Far)."""
    fig, axes = plt.subplots(1, len(panels), figsize=(4 * len(panels), 3.4), dpi=120, sharey=True)
    axes = np.atleast_1d(axes)
    for ax, (title, rows) in zip(axes, panels):
        plot_mean_sem(ax, rows, x, y, group, labels)
        ax.set_title(title)
        ax.set_xlabel(xlabel or x)
    axes[0].set_ylabel(ylabel or y)
    axes[0].legend(fontsize=8)
    return _save(fig, path)


def save_ee_paths(paths: Mapping[str, Sequence[np.ndarray]], path: str | os.PathLike,
                  objects: Sequence[Mapping] = (), title: str = "End-effector paths (top-down)") -> Path:
    """paths: {label: [(T, >=2) x, y[, z] arrays]}; objects: dicts with class_id, x, y (start poses),
    and optionally x_end, y_end. Drawn with -y to the right (east) and +x up (north)."""
    fig, ax = plt.subplots(figsize=(5, 5), dpi=120)
    cmap = plt.get_cmap("tab10")
    for i, (label, trajs) in enumerate(paths.items()):
        color = PALETTE.get(label, cmap(i % 10))
        for j, p in enumerate(trajs):
            p = np.asarray(p, dtype=float)
            if p.ndim != 2 or p.shape[0] < 2:
                continue
            ax.plot(-p[:, 1], p[:, 0], color=color, lw=1.2, alpha=0.8, label=label if j == 0 else None)
            ax.plot(-p[0, 1], p[0, 0], "o", color=color, ms=3)
    for o in objects:
        ax.plot(-o["y"], o["x"], "s", color="k", ms=6, mfc="none")
        ax.annotate(str(o.get("class_id", "")), (-o["y"], o["x"]), fontsize=7, xytext=(4, 4),
                    textcoords="offset points")
        if "x_end" in o and "y_end" in o:
            ax.annotate("", (-o["y_end"], o["x_end"]), (-o["y"], o["x"]),
                        arrowprops={"arrowstyle": "->", "color": "k", "lw": 1})
    ax.plot(0, 0, "k^", ms=8)
    ax.annotate("robot base", (0, 0), fontsize=7, xytext=(4, -10), textcoords="offset points")
    ax.set_xlabel("east  (-y, m)")
    ax.set_ylabel("north  (+x, m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.set_title(title)
    if paths:
        ax.legend(fontsize=7, loc="best")
    return _save(fig, path)


def _save(fig, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def save_task_bars(summary: Sequence[Mapping], path: str | os.PathLike, y: str = "final_state_error",
                   title: str = "Final state error per task (mean +- standard error)") -> Path:
    """Per-task mean with standard-error bars (and the success rate written above when known)."""
    fig, ax = plt.subplots(figsize=(max(4.0, 1.1 * len(summary) + 1.5), 3.6), dpi=120)
    names = [str(r["task"]) for r in summary]
    means = np.array([float(r[y]) if r[y] is not None else np.nan for r in summary])
    sems = np.array([float(r.get(f"{y}_sem") or 0.0) for r in summary])
    xs = np.arange(len(names))
    ax.bar(xs, means, yerr=sems, color="tab:blue", alpha=0.8, capsize=3)
    for x, r, m in zip(xs, summary, means):
        if r.get("success_rate") is not None:
            ax.annotate(f"{100 * r['success_rate']:.0f} %", (x, np.nan_to_num(m)), ha="center", fontsize=7,
                        xytext=(0, 6), textcoords="offset points")
    ax.set_xticks(xs, [n.replace("/", "\n") for n in names], fontsize=7)
    ax.set_ylabel("final state error (rad)")
    ax.set_title(title, fontsize=9)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def write_evaluation_report(results: Sequence, out_dir: str | os.PathLike, meta: Mapping | None = None,
                            keys: Sequence[str] = ("task",)) -> dict[str, Path]:
    """episodes.csv, summary.csv, results.json, final_state_error.png and per-task path plots."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary = summarize(results, keys)
    files = {
        "episodes": write_csv([r.row() for r in results], out / "episodes.csv"),
        "summary": write_csv(summary, out / "summary.csv"),
        "json": write_json({"meta": dict(meta or {}), "summary": summary,
                            "episodes": [r.to_json(include_path=False) for r in results]},
                           out / "results.json"),
    }
    if "task" in keys and summary:
        files["bars"] = save_task_bars(summary, out / "final_state_error.png")
    by_task: dict[str, list] = {}
    for r in results:
        by_task.setdefault(r.task, []).append(r)
    for task, rs in by_task.items():
        paths = [r.ee_path for r in rs if r.ee_path is not None and len(r.ee_path) > 1]
        if not paths:
            continue
        objects = []
        for r in rs:
            if r.object_start:
                s = r.object_start
                o = {"class_id": s["class_id"], "x": s["x"], "y": s["y"]}
                if r.object_end:
                    o.update(x_end=r.object_end["x"], y_end=r.object_end["y"])
                objects.append(o)
        label = rs[0].encoder or rs[0].model or "episodes"
        files[f"paths_{task}"] = save_ee_paths(
            {label: paths}, out / f"paths_{task.replace('/', '_')}.png", objects=objects,
            title=f"{task}: end-effector paths (top-down)")
    return files
