"""The README's lists stay true: the plugin options table is the plugins' own declarations."""

from __future__ import annotations

import pytest

from scripts.readme_options import README, with_options


@pytest.mark.mujoco
@pytest.mark.gl
@pytest.mark.hardware
def test_readme_lists_every_option_as_declared() -> None:
    text = README.read_text(encoding="utf-8")
    assert with_options(text) == text, "README.md is stale: run .venv/bin/python scripts/readme_options.py"
