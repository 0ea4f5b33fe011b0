"""``convodrive avatar``: export the built-in mannequin as glTF, or check an avatar of your own.

``avatar export --out mannequin.glb`` writes the mannequin (skinned on SMPL-X's 55 joint names,
52 ARKit morph targets) for Blender, a browser or a game engine. ``avatar check PATH`` loads a
.glb/.gltf/.vrm (or a YAML name map) exactly as ``-B render.avatar=PATH`` would and says which
bones and face channels it will drive.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from convodrive.plumbing.errors import UserError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "avatar",
        help="export the mannequin as glTF, or check your own avatar",
        description="Export the built-in mannequin as a glTF 2.0 binary, or check a glTF/VRM avatar.",
    )
    tools = p.add_subparsers(dest="tool", metavar="TOOL", required=True)
    export = tools.add_parser("export", help="write the mannequin as a .glb (skin, 52 ARKit morph targets)")
    export.add_argument(
        "--out", type=Path, default=Path("mannequin.glb"), metavar="FILE", help="output .glb (default: mannequin.glb)"
    )
    export.set_defaults(func=run_export)
    check = tools.add_parser("check", help="load an avatar as the renderer would and list what drives it")
    check.add_argument("avatar", type=Path, metavar="PATH", help=".glb, .gltf, .vrm, or a YAML name map")
    check.set_defaults(func=run_check)


def run_export(args: argparse.Namespace) -> int:
    from convodrive.backends.avatar.gltf_write import write_glb
    from convodrive.backends.avatar.mannequin import build_mannequin

    out: Path = args.out
    if out.suffix.lower() != ".glb":
        raise UserError(f"--out {out}: the file must end in .glb (a glTF 2.0 binary)")
    if out.is_dir():
        raise UserError(f"--out {out}: is a folder; give a file name ending in .glb")
    rig = build_mannequin()
    write_glb(rig, out)
    print(out)
    print(
        f"{rig.num_vertices} vertices, {sum(len(s.faces) for s in rig.surfaces)} triangles, "
        f"{rig.skeleton.num_joints} joints, {len(rig.morph_names)} ARKit morph targets"
    )
    return 0


def run_check(args: argparse.Namespace) -> int:
    from convodrive.backends.avatar.gltf_read import load_avatar
    from convodrive.backends.avatar.humanoid import CANONICAL_TO_VRM
    from convodrive.motion.channels import ARKIT_NAMES
    from convodrive.motion.skeleton import JOINT_NAMES

    rig = load_avatar(args.avatar)
    sk = rig.skeleton
    driven = {JOINT_NAMES[c] for c in sk.canonical if c >= 0}
    undriven = [CANONICAL_TO_VRM.get(n, n) for n in JOINT_NAMES if n not in driven]
    missing = [n for n in ARKIT_NAMES if n not in rig.morph_names]
    print(f"{args.avatar}: {rig.num_vertices} vertices, {len(rig.surfaces)} surfaces, {sk.num_joints} joints")
    print(
        f"bones driven: {len(driven)} of {len(JOINT_NAMES)}"
        + (f" (not in the avatar: {', '.join(undriven)})" if undriven else "")
    )
    print(
        f"face channels with a morph target: {len(rig.morph_names)} of {len(ARKIT_NAMES)}"
        + (f" (none for: {', '.join(missing)})" if missing else "")
    )
    if "jawOpen" not in rig.morph_names:
        print(
            "no jawOpen morph target: the jaw bone opens the mouth"
            if "jaw" in driven
            else "no jawOpen morph target and no jaw bone: the mouth will not open"
        )
    return 0
