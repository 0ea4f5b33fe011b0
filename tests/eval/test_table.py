"""eval compare's outputs: every distance also as a ratio to the ground-truth takes' (the floor)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from convodrive.eval.table import FLOOR_COLUMNS, markdown, write_outputs
from tests.conftest import require

RESULTS = {
    "ground-truth": {"FD_g body": 5.0, "FD_g face": 0.5, "FGD holistic": 20.0, "lip r": 0.8},
    "knn": {"FD_g body": 6.0, "FD_g face": 1.0, "FGD holistic": 30.0, "lip r": 0.1},
    "a2p": {"FD_g body": 10.0, "FD_g face": None, "FGD holistic": 25.0, "lip r": 0.7},
}


@require("matplotlib")
def test_the_json_gives_each_distance_over_the_floors(tmp_path: Path) -> None:
    write_outputs(RESULTS, tmp_path, "t", {})
    ratios = json.loads((tmp_path / "compare.json").read_text())["ratio_to_ground_truth"]
    assert set(ratios) == set(RESULTS) and set(ratios["knn"]) == set(FLOOR_COLUMNS)
    assert ratios["ground-truth"]["FD_g body"] == 1.0
    assert ratios["knn"]["FD_g body"] == pytest.approx(1.2) and ratios["a2p"]["FGD holistic"] == pytest.approx(1.25)
    assert ratios["a2p"]["FD_g face"] is None and ratios["a2p"]["FD_k body"] is None  # not measured
    assert "lip r" not in ratios["knn"]  # not a distance


def test_the_table_shows_the_ratios_only_when_the_floor_was_scored() -> None:
    table = markdown(RESULTS, "t")
    section = table.split("ratio to the ground-truth")[1]
    assert "| knn | 1.2 | 2 |" in section and "| a2p | 2 | — |" in section
    without = {m: f for m, f in RESULTS.items() if m != "ground-truth"}
    assert "ratio to the" not in markdown(without, "t")


def test_the_parts_section_appears_with_part_figures_and_their_ratios() -> None:
    assert "by part" not in markdown(RESULTS, "t")
    parts = {m: {**f, "FD_g hands": h} for (m, f), h in zip(RESULTS.items(), (2.0, 3.0, 8.0))}
    table = markdown(parts, "t").split("## FD_g by part")[1]
    values, ratios = table.split("As a ratio to the ground-truth takes'")
    assert "| a2p | — | — | 8 |" in values and "| a2p | — | — | 4 |" in ratios
