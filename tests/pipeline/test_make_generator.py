"""A live run takes a generator's low-latency defaults; the config and the command line still win."""

from __future__ import annotations

from pathlib import Path

from convodrive.pipeline.config import load_run_config
from convodrive.pipeline.run import make_generator


def test_live_runs_use_the_generators_live_defaults(tmp_path: Path) -> None:
    none = load_run_config(None)
    offline, _ = make_generator("procedural", none, {})
    live, options = make_generator("procedural", none, {}, live=True)
    assert offline.lookahead_frames == 12 and live.lookahead_frames == 3  # 400 ms for files, 100 ms live
    assert options.anticipation == 0.0
    asked, _ = make_generator("procedural", none, {"anticipation": 0.2}, live=True)
    assert asked.lookahead_frames == 3 + 6
    config = tmp_path / "run.yaml"
    config.write_text("generator:\n  procedural:\n    anticipation: 0.1\n")
    from_config, _ = make_generator("procedural", load_run_config(config), {}, live=True)
    assert from_config.lookahead_frames == 3 + 3
