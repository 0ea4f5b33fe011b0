"""Make the avatar pictures the README shows, from the bundled dialogue:

    .venv/bin/python scripts/docs_avatar_images.py

- ``docs/avatar_upper.png`` and ``docs/avatar_face.png``: contact sheets of the mannequin driven
  by the procedural generator, upper-body and face cameras, each frame labelled with who talks;
- ``docs/avatar_gltf.png``: one frame of the same motion on the built-in mannequin, on the
  mannequin exported with ``convodrive avatar export`` and loaded back as a file, and on a second
  glTF avatar (other proportions, bone axes, A-pose rest, VRM bone names, prefixed morph target
  names: the one ``tests/backends/avatar/test_gltf.py`` builds), with the first two's difference.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
CONVODRIVE = [sys.executable, "-m", "convodrive.cli.main"]
GLTF_FRAME_SECONDS = 24.5


def run(*args: str) -> None:
    subprocess.run([*CONVODRIVE, *args], check=True, cwd=ROOT, stdout=subprocess.DEVNULL)


def label(image: np.ndarray, text: str) -> np.ndarray:
    img = Image.fromarray(image)
    draw = ImageDraw.Draw(img)
    draw.rectangle((0, 0, 8 + 6 * len(text), 16), fill=(0, 0, 0))
    draw.text((4, 2), text, fill=(255, 255, 255))
    return np.asarray(img)


def main() -> None:
    sys.path.insert(0, str(ROOT))
    from convodrive.backends.avatar.gltf_read import load_avatar
    from convodrive.backends.avatar.mannequin import build_mannequin
    from convodrive.backends.avatar.render_scene import AvatarRenderer
    from convodrive.motion.npz import load_clip
    from tests.backends.avatar.test_gltf import VRM_NAMES, _write, other_avatar

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        run("drive", "samples/dialogue.wav", "--backend", "record", "--out", str(work))
        motion = work / "motion.npz"
        for camera in ("upper", "face"):
            run("render", str(motion), "--camera", camera, "--out", str(work / f"{camera}.mp4"))
            Image.open(work / f"{camera}_contact.png").save(DOCS / f"avatar_{camera}.png", optimize=True)
        run("avatar", "export", "--out", str(work / "mannequin.glb"))
        other = _write(other_avatar(VRM_NAMES, lambda n: f"blendShape1.{n[0].upper()}{n[1:]}"), work / "other.glb")
        frame = load_clip(motion).frame(int(GLTF_FRAME_SECONDS * 30))
        tiles = []
        for rig in (build_mannequin(), load_avatar(work / "mannequin.glb"), load_avatar(other)):
            renderer = AvatarRenderer(384, 384, "upper", rig=rig)
            tiles.append(renderer.render(frame))
            renderer.close()
        diff = np.abs(tiles[0].astype(int) - tiles[1].astype(int)).max(-1)
        print(
            f"built-in vs exported: mean {diff.mean():.4f}, max {diff.max()} levels, {int((diff > 0).sum())} pixels differ"
        )
        shown = np.clip(255 - diff * 40, 0, 255).astype(np.uint8)  # any difference at all shows dark
        row = [
            label(tiles[0], "built-in mannequin"),
            label(tiles[1], "mannequin.glb, loaded"),
            label(np.dstack([shown] * 3), f"difference (max {diff.max()} of 255)"),
            label(tiles[2], "another glTF avatar"),
        ]
        Image.fromarray(np.concatenate(row, 1)).save(DOCS / "avatar_gltf.png", optimize=True)


if __name__ == "__main__":
    main()
