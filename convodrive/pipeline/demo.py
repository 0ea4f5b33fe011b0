"""The demo's run: the bundled dialogue into every body we ship, the servo head emulated.

``convodrive demo`` and the scheduler benchmark's mixed case both run exactly this, so the figures
the benchmark prints are the demo's.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from convodrive.pipeline.run import DEFAULT_GENERATOR, DriveRequest

DEMO_BACKENDS = ("record", "render", "mujoco", "dynamixel")


@contextlib.contextmanager
def demo_request(out_dir: Path, backends: Sequence[str] = DEMO_BACKENDS, seed: int = 0) -> Iterator[DriveRequest]:
    """The demo's drive request, with an emulated Dynamixel head serving while the context is open."""
    from convodrive.samples import bundled_dialogue

    with contextlib.ExitStack() as stack:
        backend_options: dict[str, dict[str, Any]] = {"render": {"camera": "upper"}} if "render" in backends else {}
        if "dynamixel" in backends:
            from convodrive.backends.servo.dynamixel_emulator import emulated_head_process

            port = stack.enter_context(emulated_head_process())
            # The emulator is a process on a busy machine (the renderer and MuJoCo film beside
            # it), so allow its status packets more time than a USB adapter would need.
            backend_options["dynamixel"] = {"port": port, "latency_ms": 40}
        yield DriveRequest(
            audio=bundled_dialogue(),
            generator=DEFAULT_GENERATOR,
            backends=tuple(backends),
            out_dir=out_dir,
            seed=seed,
            backend_options=backend_options,
        )
