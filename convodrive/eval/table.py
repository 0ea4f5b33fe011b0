"""The outputs of ``eval compare``: a Markdown table, the same figures as JSON, and a PNG plot.

When the ground-truth takes were scored, every method's distances (FD and FGD) are also given as a
ratio to theirs: the other takes of the same audio are the floor the data sets, so 1.0 is as close
as a method can be expected to come, and a bare distance says little on its own.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from convodrive.eval.suite import COLUMNS, PART_COLUMNS
from convodrive.plumbing.atomic import atomic_path, write_text_atomic

FLOOR = "ground-truth"
GROUP_DISTANCES = tuple(n for n, _, _ in COLUMNS if n.startswith(("FD_", "FGD")))
"""The distances of the main table, given with their ratio and spread in tables of their own."""
FLOOR_COLUMNS = GROUP_DISTANCES + PART_COLUMNS
"""The distances given as a ratio to the floor's."""
PLOTTED = ("FD_g body", "FD_g face", "FGD holistic", "FD_k body", "Div_sample", "BC", "lip r", "mouth shut")


def _cell(value: float | None) -> str:
    return "—" if value is None else f"{value:.3g}"


def floor_ratios(results: dict[str, dict[str, Any]]) -> dict[str, dict[str, float | None]]:
    """Each method's distances over the ground-truth takes' (empty when those were not scored)."""
    floor = results.get(FLOOR)
    if floor is None:
        return {}

    def ratio(value: float | None, base: float | None) -> float | None:
        return None if value is None or not base else value / base

    return {m: {n: ratio(fig.get(n), floor.get(n)) for n in FLOOR_COLUMNS} for m, fig in results.items()}


def _table(columns: list[str], rows: dict[str, dict[str, Any]]) -> list[str]:
    header = "| method | " + " | ".join(columns) + " |"
    rule = "|---|" + "---|" * len(columns)
    return [header, rule, *(f"| {m} | " + " | ".join(_cell(v) for v in fig.values()) + " |" for m, fig in rows.items())]


def _parts_section(results: dict[str, dict[str, Any]], ratios: dict[str, dict[str, float | None]]) -> list[str]:
    """FD_g by part, and over the floor's when it was scored; nothing when no method has them."""
    parts = {m: {n: fig.get(n) for n in PART_COLUMNS} for m, fig in results.items()}
    if all(v is None for fig in parts.values() for v in fig.values()):
        return []
    lines = ["## FD_g by part (each part's channels alone; they do not add up to the group's)", ""]
    lines += [*_table([f"{n} ↓" for n in PART_COLUMNS], parts), ""]
    if ratios:
        lines += [f"As a ratio to the {FLOOR} takes':", ""]
        lines += [*_table(list(PART_COLUMNS), {m: {n: r[n] for n in PART_COLUMNS} for m, r in ratios.items()}), ""]
    return lines


def markdown(results: dict[str, dict[str, Any]], title: str, spread: dict[str, dict[str, Any]] | None = None) -> str:
    """``spread``: each method's standard deviation of each figure over seeds, when several ran."""
    arrows = {"low": " ↓", "high": " ↑", "": ""}
    figures = {m: {n: fig.get(n) for n, _, _ in COLUMNS} for m, fig in results.items()}
    lines = [f"# {title}", "", *_table([f"{n}{arrows[b]}" for n, b, _ in COLUMNS], figures), ""]
    ratios = floor_ratios(results)
    if ratios:
        lines += [f"## Distances as a ratio to the {FLOOR} takes' (1 is the floor the data sets)", ""]
        group_ratios = {m: {n: r[n] for n in GROUP_DISTANCES} for m, r in ratios.items()}
        lines += [*_table([f"{n} ↓" for n in GROUP_DISTANCES], group_ratios), ""]
    lines += _parts_section(results, ratios)
    if spread:
        lines += ["## Standard deviation over the seeds (each seed: the same conversations, new samples)", ""]
        lines += [
            *_table(list(GROUP_DISTANCES), {m: {n: sd.get(n) for n in GROUP_DISTANCES} for m, sd in spread.items()}),
            "",
        ]
    lines += [f"- **{n}**{arrows[b]}: {what}" for n, b, what in COLUMNS]
    return "\n".join(lines) + "\n"


def plot(results: dict[str, dict[str, Any]], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = list(results)
    fig, axes = plt.subplots(2, 4, figsize=(16, 7), constrained_layout=True)
    colours = plt.get_cmap("tab10")(range(len(methods)))
    better = {n: b for n, b, _ in COLUMNS}
    for ax, name in zip(axes.ravel(), PLOTTED):
        values = [results[m].get(name) for m in methods]
        ax.bar(range(len(methods)), [0 if v is None else v for v in values], color=colours)
        ax.set_xticks(range(len(methods)), methods, rotation=30, ha="right", fontsize=8)
        ax.set_title(f"{name} ({'lower' if better[name] == 'low' else 'higher'} is better)", fontsize=10)
        for i, v in enumerate(values):
            ax.annotate(_cell(v), (i, 0 if v is None else v), ha="center", va="bottom", fontsize=7)
    fig.suptitle(title)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)


def write_outputs(results: dict[str, dict[str, Any]], out: Path, title: str, context: dict[str, Any]) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    md, js, png = out / "compare.md", out / "compare.json", out / "compare.png"
    write_text_atomic(md, markdown(results, title, context.get("sd_over_seeds")))
    columns = [{"name": n, "better": b, "definition": w} for n, b, w in COLUMNS]
    document = {**context, "columns": columns, "results": results, "ratio_to_ground_truth": floor_ratios(results)}
    write_text_atomic(js, json.dumps(document, indent=2) + "\n")
    plot(results, png, title)
    return [md, js, png]
