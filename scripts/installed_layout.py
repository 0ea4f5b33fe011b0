"""Mirror the installed package layout in a folder, files linked back to the repository.

retargeting/, backends/, sims/, config/ and samples/ sit at the top of the repository but install
as convodrive.retargeting, convodrive.backends, ... (pyproject's ``package-dir``). Tools that read
packages from the file system (mypy, import-linter) need them where the installed tree has them.

    python scripts/installed_layout.py DEST
"""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def mirror(dest: Path) -> None:
    package_dir: dict[str, str] = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-dir"
    ]
    # Shorter package names first, so convodrive/ exists before convodrive/backends/ is placed in it.
    for package, folder in sorted(package_dir.items(), key=lambda kv: kv[0].count(".")):
        target = dest.joinpath(*package.split("."))
        for path in sorted((REPO / folder).rglob("*.py")):
            relative = path.relative_to(REPO / folder)
            if "__pycache__" in relative.parts or "build" in relative.parts:
                continue
            if relative.parts[0] in {"backends", "retargeting", "sims", "config", "samples"} and folder == "convodrive":
                continue
            link = target / relative
            link.parent.mkdir(parents=True, exist_ok=True)
            if not link.exists():
                link.symlink_to(path)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: installed_layout.py DEST")
    mirror(Path(sys.argv[1]))
