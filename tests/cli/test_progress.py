"""What the console shows while backends finish after the clock (a real-time run's videos lag)."""

from __future__ import annotations

import pytest

from convodrive.cli.progress import drain_progress


def test_the_bar_names_the_backends_still_writing() -> None:
    seen: list[tuple] = []
    update = drain_progress(lambda *args: seen.append(args), "demo")
    update(10, 300, ["render", "mujoco"])
    update(200, 300, ["mujoco"])
    assert seen == [(10, 300, "finishing render, mujoco"), (200, 300, "finishing mujoco")]


def test_without_a_bar_a_long_wait_is_said_once(capsys: pytest.CaptureFixture[str]) -> None:
    update = drain_progress(None, "demo")
    update(0, 10, ["dynamixel"])  # a servo easing for a moment: nothing to say
    update(5, 400, ["render", "mujoco"])
    update(100, 400, ["render"])
    assert capsys.readouterr().err == "demo: finishing render, mujoco (395 frames still to write)\n"
