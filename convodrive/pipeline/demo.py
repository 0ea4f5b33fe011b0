"""The demo's run: the bundled dialogue (or a conversation of the user's) into every body we ship,
the servo head emulated.

``convodrive demo`` and the scheduler benchmark's mixed case both run exactly this, so the figures
the benchmark prints are the demo's.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from convodrive.pipeline.run import DEFAULT_GENERATOR, DriveRequest

DEMO_BACKENDS = ("record", "render", "mujoco", "dynamixel")


@contextlib.contextmanager
def demo_request(
    out_dir: Path, backends: Sequence[str] = DEMO_BACKENDS, seed: int = 0, audio: Path | None = None
) -> Iterator[DriveRequest]:
    """The demo's drive request (``audio``, else the bundled dialogue), with an emulated Dynamixel
    head serving while the context is open."""
    from convodrive.samples import bundled_dialogue

    with contextlib.ExitStack() as stack:
        backend_options: dict[str, dict[str, Any]] = {"render": {"camera": "upper"}} if "render" in backends else {}
        if "dynamixel" in backends:
            from convodrive.backends.servo.emulated_head import emulated_head_process

            port = stack.enter_context(emulated_head_process())
            # The emulator is a process on a busy machine (the renderer and MuJoCo film beside
            # it), so allow its status packets more time than a USB adapter would need.
            backend_options["dynamixel"] = {"port": port, "latency_ms": 40}
        yield DriveRequest(
            audio=audio or bundled_dialogue(),
            generator=DEFAULT_GENERATOR,
            backends=tuple(backends),
            out_dir=out_dir,
            seed=seed,
            backend_options=backend_options,
        )


SIDE_BY_SIDE_GENERATORS = ("procedural", "probtalk", "a2p")
"""The generators the demo films side by side: the default and the two papers' learned models."""


@dataclasses.dataclass
class SideBySide:
    video: Path | None
    """The side-by-side video, or None when no generator could run."""
    generators: list[str]
    skipped: dict[str, str]
    """Generators left out, each with the one-line reason (no model shipped, extra missing)."""


def side_by_side(
    out_dir: Path,
    generators: Sequence[str] = SIDE_BY_SIDE_GENERATORS,
    seed: int = 0,
    resolution: str = "384x384",
    audio: Path | None = None,
) -> SideBySide:
    """The conversation (``audio``, else the bundled dialogue) through each generator (offline,
    into the recorder), then one video of their motion side by side, captioned, with the
    conversation's audio: ``side_by_side.mp4``.

    A generator that cannot run here (its model or extra missing) is skipped with its reason, so
    the demo still shows what it can."""
    from convodrive.pipeline.run import drive
    from convodrive.plumbing.errors import UserError
    from convodrive.samples import bundled_dialogue

    audio = audio or bundled_dialogue()
    work = out_dir / "side_by_side"
    clips: list[Path] = []
    ran: list[str] = []
    skipped: dict[str, str] = {}
    for name in generators:
        try:
            drive(
                DriveRequest(
                    audio=audio,
                    generator=name,
                    backends=("record",),
                    out_dir=work / name,
                    seed=seed,
                    realtime=False,
                    out_label=f"{work / name}",
                )
            )
        except UserError as exc:
            skipped[name] = str(exc)
            continue
        clips.append(work / name / "motion.npz")
        ran.append(name)
    if not clips:
        return SideBySide(None, ran, skipped)
    drive(
        DriveRequest(
            audio=audio,
            generator="replay",
            generator_options={"motion": [str(p) for p in clips]},
            backends=("render",),
            backend_options={
                "render": {
                    "camera": "upper",
                    "resolution": resolution,
                    "filename": "side_by_side.mp4",
                    "contact_sheet": "side_by_side_contact.png",
                    "labels": ",".join(ran),
                }
            },
            samples=len(clips),
            realtime=False,
            out_dir=out_dir,
            report_name="side_by_side_report",
        )
    )
    return SideBySide(out_dir / "side_by_side.mp4", ran, skipped)
