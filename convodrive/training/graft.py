"""``convodrive export RUN --out DIR --onto MODEL_DIR --graphs NAME[,NAME]``: a model folder that is
MODEL_DIR with some of its graphs exported anew from RUN.

For weights whose torch checkpoints are gone: a later stage (probtalk's refiner) retrained on top
of them replaces its own graph and keeps every other one to the bit. The two folders must be of the
same model and data (the same feature layout, speakers and normalisation files), and the settings
in which they differ must belong to the replaced graphs (named after them: ``refiner_*``).
``model.json`` records what each replaced graph was trained from under ``grafted``; the model
card is MODEL_DIR's, which its maker brings up to date.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from convodrive.neural.folder import MODEL_JSON, load_model_folder, sha256_file
from convodrive.plumbing.atomic import atomic_folder
from convodrive.plumbing.errors import UserError


def _verified(folder: Path) -> dict[str, Any]:
    """``folder``'s model.json as plain JSON, every file's sha256 checked (``load_model_folder``)."""
    return json.loads(json.dumps(load_model_folder(folder).spec))


def _owned(names: Sequence[str]) -> tuple[str, ...]:
    """The prefixes of the settings the replaced graphs own: ``refiner`` owns ``refiner_*``."""
    return tuple(f"{n.split('_')[0]}_" for n in names)


def check_onto(onto: Path, names: Sequence[str]) -> None:
    """Before any export: ``onto`` is a model folder holding each of ``names``."""
    _check_names(load_model_folder(onto).graphs, names, onto)


def _check_names(graphs: dict[str, Any], names: Sequence[str], onto: Path) -> None:
    missing = [n for n in names if n not in graphs]
    if not names or missing:
        raise UserError(f"--graphs {','.join(missing) or '(none)'}: not a graph of {onto} ({', '.join(graphs)})")


def check_graftable(source: dict[str, Any], base: dict[str, Any], names: Sequence[str], onto: Path) -> None:
    """The checks the module docstring names beyond ``check_onto``'s, each a one-line ``UserError``."""
    if source.get("model") != base.get("model"):
        raise UserError(f"--onto {onto}: a {base.get('model')} model, the run is {source.get('model')}")
    missing = [n for n in names if n not in source["graphs"]]
    if missing:
        raise UserError(
            f"--graphs {','.join(missing)}: not a graph of the run's export ({', '.join(source['graphs'])})"
        )
    graph_files = {g["file"] for g in (*source["graphs"].values(), *base["graphs"].values())}
    data = {f: h for f, h in base["files"].items() if f not in graph_files}
    if source.get("features") != base.get("features") or any(source["files"].get(f) != h for f, h in data.items()):
        raise UserError(f"--onto {onto}: learnt from other data (its features or normalisation differ from the run's)")
    arch, theirs = source.get("architecture", {}), base.get("architecture", {})
    # A setting only one folder has was added after the other was made; its default is the old behaviour.
    foreign = sorted(k for k in set(arch) & set(theirs) if arch[k] != theirs[k] and not k.startswith(_owned(names)))
    if foreign:
        raise UserError(f"--onto {onto}: other settings than the replaced graphs' ({', '.join(foreign)})")


def graft(source: Path, onto: Path, names: Sequence[str], out: Path) -> None:
    """Write ``out``: ``onto`` with the graphs ``names`` of the exported folder ``source``."""
    src, base = _verified(source), _verified(onto)
    _check_names(base["graphs"], names, onto)
    check_graftable(src, base, names, onto)
    meta = json.loads(json.dumps(base))
    with atomic_folder(out) as tmp:
        replaced = {base["graphs"][n]["file"] for n in names}
        for path in onto.iterdir():
            if path.is_file() and path.name not in replaced and path.name != MODEL_JSON:
                shutil.copy2(path, tmp / path.name)
        for name in names:
            shutil.copy2(source / src["graphs"][name]["file"], tmp / src["graphs"][name]["file"])
            _take_graph(meta, src, name)
        prefixes = _owned(names)
        meta["architecture"] = {
            **{k: v for k, v in base.get("architecture", {}).items() if not k.startswith(prefixes)},
            **{k: v for k, v in src.get("architecture", {}).items() if k.startswith(prefixes)},
        }
        meta["files"] = {p.name: sha256_file(p) for p in sorted(tmp.iterdir()) if p.name != "MODEL_CARD.md"}
        (tmp / MODEL_JSON).write_text(json.dumps(meta, indent=2), encoding="utf-8")


def _take_graph(meta: dict[str, Any], src: dict[str, Any], name: str) -> None:
    """``meta`` (the copy of --onto's model.json) with graph ``name``'s entries from ``src``."""
    meta["graphs"][name] = src["graphs"][name]
    meta["parity"]["max_abs_err"][name] = src["parity"]["max_abs_err"][name]
    if meta.get("int8"):  # the graph comes int8 with its cost, or float
        meta["int8"]["cost"].pop(name, None)
        cost = (src.get("int8") or {}).get("cost", {})
        if name in cost:
            meta["int8"]["cost"][name] = cost[name]
        meta["int8"]["float"] = sorted({*meta["int8"]["float"], name} - set(cost))
    meta.setdefault("grafted", {})[name] = {"stage": src.get("stage"), "training": src.get("training")}
