"""The checks of a robot profile: each value parsed into ``profile_schema`` objects, or one line
naming the file and the key path (``InputFileError``), never a traceback in the middle of a run."""

from __future__ import annotations

import dataclasses
import difflib
import importlib.resources
import math
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.motion.channels import BLENDSHAPE_INDEX
from convodrive.motion.skeleton import JOINT_INDEX
from convodrive.plumbing.errors import InputFileError
from convodrive.plumbing.safe_yaml import number_text
from convodrive.plumbing.text import clip_value
from convodrive.retargeting.profile_schema import (
    AXES,
    FILTERS,
    JOINT_KEYS,
    MAX_MAGNITUDE,
    TERM_KEYS,
    UNITS,
    IKConfig,
    IKTask,
    JointMap,
    Smoothing,
    Term,
)


class Checker:
    """Raises one-line errors naming the file and the key path."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, key: str, problem: str) -> None:
        raise InputFileError(self.source, f"{key}: {problem}" if key else problem)

    def mapping(self, value: Any, key: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            self.fail(key, f"must be a mapping, got {type(value).__name__}")
        return value

    def keys(self, value: dict[str, Any], allowed: tuple[str, ...], key: str) -> None:
        for k in value:
            if k not in allowed:
                close = difflib.get_close_matches(str(k), allowed, n=1, cutoff=0.6)
                hint = f"did you mean '{close[0]}'?" if close else f"expected one of: {', '.join(allowed)}"
                name = clip_value(str(k), 40).strip("'")
                self.fail(f"{key}.{name}" if key else name, f"unknown key ({hint})")

    def number(self, value: Any, key: str, positive: bool = False, unlimited: bool = False) -> float:
        """A finite number of sane size; ``unlimited`` also admits ``inf`` (an absent limit)."""
        if isinstance(value, str) and unlimited and value.strip().lower() in ("inf", ".inf"):
            value = math.inf
        value = number_text(value)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(key, f"must be a number, got {clip_value(value)}")
        if isinstance(value, int) and abs(value) > MAX_MAGNITUDE:  # may be too large for a float
            self.fail(
                key, f"must be at most {MAX_MAGNITUDE:g} in size, got an integer of {len(str(abs(value)))} digits"
            )
        if math.isnan(value) or (math.isinf(value) and not (unlimited and value > 0)):
            self.fail(key, f"must be a finite number, got {value}")
        if math.isfinite(value) and abs(value) > MAX_MAGNITUDE:
            self.fail(key, f"must be at most {MAX_MAGNITUDE:g} in size, got {value:g}")
        if positive and value <= 0:
            self.fail(key, f"must be positive, got {value}")
        return float(value)

    def string(self, value: Any, key: str) -> str:
        if not isinstance(value, str) or not value:
            self.fail(key, f"must be a non-empty string, got {clip_value(value)}")
        return value

    def canonical_joint(self, value: Any, key: str) -> str:
        name = self.string(value, key)
        if name not in JOINT_INDEX:
            self.fail(key, f"unknown canonical joint {clip_value(name)}")
        return name

    def axis(self, value: Any, key: str, order: str = AXES) -> int:
        if isinstance(value, str) and value.upper() in order:
            return order.index(value.upper())
        if isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= 2:
            return value
        self.fail(key, f"must be 0, 1, 2 or one of {', '.join(order)}, got {clip_value(value)}")
        raise AssertionError


def _parse_map(ck: Checker, value: Any, key: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    if not isinstance(value, list) or len(value) < 2:
        ck.fail(key, "must be a list of at least two [x, y] points")
    xs, ys = [], []
    for i, point in enumerate(value):
        if not isinstance(point, list) or len(point) != 2:
            ck.fail(f"{key}[{i}]", f"must be an [x, y] pair, got {clip_value(point)}")
        xs.append(ck.number(point[0], f"{key}[{i}][0]"))
        ys.append(ck.number(point[1], f"{key}[{i}][1]"))
    if any(b <= a for a, b in zip(xs, xs[1:])):
        ck.fail(key, f"map is not monotonic: x must increase strictly, got {xs}")
    dy = np.diff(ys)
    if np.any(dy > 0) and np.any(dy < 0):
        ck.fail(key, f"map is not monotonic: y must only rise or only fall, got {ys}")
    return tuple(xs), tuple(ys)


def _parse_term(ck: Checker, value: Any, key: str) -> Term:
    term = ck.mapping(value, key)
    ck.keys(term, TERM_KEYS, key)
    kinds = [k for k in ("rotation", "blendshape", "translation") if k in term]
    if len(kinds) != 1:
        ck.fail(key, "needs exactly one of rotation, blendshape, translation")
    kind = kinds[0]
    weight = ck.number(term.get("weight", 1.0), f"{key}.weight")
    map_x = map_y = None
    if "map" in term:
        map_x, map_y = _parse_map(ck, term["map"], f"{key}.map")
    if kind == "rotation":
        raw = term["rotation"]
        names = raw if isinstance(raw, list) else [raw]
        if not names:
            ck.fail(f"{key}.rotation", "names no joint")
        chain = tuple(ck.canonical_joint(n, f"{key}.rotation") for n in names)
        order = term.get("euler", "XYZ")
        if not isinstance(order, str) or len(order) != 3 or set(order.upper()) != set(AXES):
            ck.fail(f"{key}.euler", f"must be a permutation of XYZ such as ZXY, got {clip_value(order)}")
        order = order.upper()
        if "axis" not in term:
            ck.fail(f"{key}.axis", "is required with rotation (which Euler angle drives the joint)")
        return Term(
            "rotation",
            chain=chain,
            euler=order,
            axis=ck.axis(term["axis"], f"{key}.axis", order),
            weight=weight,
            map_x=map_x,
            map_y=map_y,
        )
    for extra in ("euler", "axis"):
        if extra in term and kind == "blendshape":
            ck.fail(f"{key}.{extra}", "only applies to a rotation term")
    if kind == "blendshape":
        channel = ck.string(term["blendshape"], f"{key}.blendshape")
        if channel not in BLENDSHAPE_INDEX:
            ck.fail(f"{key}.blendshape", f"unknown channel {clip_value(channel)} (expected an ARKit blendshape name)")
        return Term("blendshape", channel=channel, weight=weight, map_x=map_x, map_y=map_y)
    return Term(
        "translation", axis=ck.axis(term["translation"], f"{key}.translation"), weight=weight, map_x=map_x, map_y=map_y
    )


def parse_smoothing(ck: Checker, value: Any, key: str, base: Smoothing) -> Smoothing:
    if value is None or value == "none" or value is False:
        return Smoothing(filter="none")
    sm = ck.mapping(value, key)
    ck.keys(sm, ("filter", "min_cutoff", "beta", "d_cutoff", "time_constant"), key)
    kind = sm.get("filter", base.filter)
    if kind not in FILTERS:
        ck.fail(f"{key}.filter", f"unknown filter {clip_value(kind)} (expected one of: {', '.join(FILTERS)})")
    fields = {"filter": kind}
    for name in ("min_cutoff", "d_cutoff", "time_constant"):
        if name in sm:
            fields[name] = ck.number(sm[name], f"{key}.{name}", positive=True)
    if "beta" in sm:
        fields["beta"] = ck.number(sm["beta"], f"{key}.beta")
        if fields["beta"] < 0:
            ck.fail(f"{key}.beta", "must not be negative")
    return dataclasses.replace(base, **fields)


def parse_joint(ck: Checker, name: str, value: Any, smoothing: Smoothing, by_ik: bool) -> JointMap:
    key = f"joints.{name}"
    spec = ck.mapping(value, key)
    ck.keys(spec, JOINT_KEYS, key)
    if "source" in spec and "sum" in spec:
        ck.fail(key, "needs one of source or sum, not both")
    if "source" not in spec and "sum" not in spec:
        if not by_ik:
            ck.fail(key, "needs a source or a sum (or must be listed under ik.joints)")
        terms: tuple[Term, ...] = ()  # IK sets it; offset is the seed
    elif "source" in spec:
        terms = (_parse_term(ck, spec["source"], f"{key}.source"),)
    else:
        if not isinstance(spec["sum"], list) or not spec["sum"]:
            ck.fail(f"{key}.sum", "must be a non-empty list of terms")
        terms = tuple(_parse_term(ck, t, f"{key}.sum[{i}]") for i, t in enumerate(spec["sum"]))
    if "limits" not in spec:
        ck.fail(f"{key}.limits", "is required: [min, max]")
    lim = spec["limits"]
    if not isinstance(lim, list) or len(lim) != 2:
        ck.fail(f"{key}.limits", f"must be [min, max], got {clip_value(lim)}")
    lower, upper = ck.number(lim[0], f"{key}.limits[0]"), ck.number(lim[1], f"{key}.limits[1]")
    if lower > upper:
        ck.fail(f"{key}.limits", f"min {lower} is above max {upper}")
    direction = ck.number(spec.get("direction", 1), f"{key}.direction")
    if direction not in (1.0, -1.0):
        ck.fail(f"{key}.direction", f"must be 1 or -1, got {clip_value(spec['direction'])}")
    units = spec.get("units", "rad")
    if units not in UNITS:
        ck.fail(f"{key}.units", f"must be one of {', '.join(UNITS)}, got {clip_value(units)}")
    neutral = ck.number(spec.get("neutral", 0.0), f"{key}.neutral")
    return JointMap(
        name=name,
        terms=terms,
        gain=ck.number(spec.get("gain", 1.0), f"{key}.gain"),
        offset=ck.number(spec.get("offset", 0.0), f"{key}.offset"),
        direction=direction,
        lower=lower,
        upper=upper,
        max_velocity=ck.number(
            spec.get("max_velocity", math.inf), f"{key}.max_velocity", positive=True, unlimited=True
        ),
        max_acceleration=ck.number(
            spec.get("max_acceleration", math.inf), f"{key}.max_acceleration", positive=True, unlimited=True
        ),
        neutral=min(max(neutral, lower), upper),
        units=units,
        smoothing=parse_smoothing(ck, spec["smoothing"], f"{key}.smoothing", smoothing)
        if "smoothing" in spec
        else smoothing,
    )


def _parse_axes(ck: Checker, value: Any, key: str) -> np.ndarray:
    """``[z, x, y]``: robot X is canonical Z, and so on; a leading ``-`` flips a sign."""
    if not isinstance(value, list) or len(value) != 3:
        ck.fail(key, f"must list three canonical axes such as [z, x, y], got {clip_value(value)}")
    m = np.zeros((3, 3))
    for row, item in enumerate(value):
        text = str(item).strip().lower()
        sign = -1.0 if text.startswith("-") else 1.0
        text = text.lstrip("+-")
        if text not in ("x", "y", "z"):
            ck.fail(f"{key}[{row}]", f"must be x, y or z with an optional sign, got {clip_value(item)}")
        m[row, "xyz".index(text)] = sign
    if abs(abs(np.linalg.det(m)) - 1.0) > 1e-9:
        ck.fail(key, "must use each axis once")
    return m


def parse_ik(ck: Checker, value: Any, joints: dict[str, JointMap]) -> IKConfig:
    ik = ck.mapping(value, "ik")
    ck.keys(ik, ("joints", "root", "tasks", "axes", "scale", "posture_cost", "iterations", "damping", "solver"), "ik")
    names = ik.get("joints")
    if not isinstance(names, list) or not names:
        ck.fail("ik.joints", "must list the profile joints that IK sets")
    for i, n in enumerate(names):
        if n not in joints:
            ck.fail(f"ik.joints[{i}]", f"unknown joint {clip_value(n)} (not under joints:)")
        if n in names[:i]:
            ck.fail(f"ik.joints[{i}]", f"joint {clip_value(n)} is listed twice")
    root = ck.mapping(ik.get("root"), "ik.root")
    ck.keys(root, ("canonical", "body"), "ik.root")
    root_canonical = ck.canonical_joint(root.get("canonical"), "ik.root.canonical")
    root_body = ck.string(root.get("body"), "ik.root.body")
    raw_tasks = ik.get("tasks")
    if not isinstance(raw_tasks, list) or not raw_tasks:
        ck.fail("ik.tasks", "must be a non-empty list")
    tasks = []
    for i, t in enumerate(raw_tasks):
        key = f"ik.tasks[{i}]"
        t = ck.mapping(t, key)
        ck.keys(t, ("frame", "type", "canonical", "anchor", "position_cost", "orientation_cost"), key)
        frame_type = t.get("type", "body")
        if frame_type not in ("body", "site", "geom"):
            ck.fail(f"{key}.type", f"must be body, site or geom, got {clip_value(frame_type)}")
        anchor = ck.mapping(t.get("anchor", {"canonical": root_canonical, "body": root_body}), f"{key}.anchor")
        ck.keys(anchor, ("canonical", "body"), f"{key}.anchor")
        tasks.append(
            IKTask(
                frame=ck.string(t.get("frame"), f"{key}.frame"),
                frame_type=frame_type,
                canonical=ck.canonical_joint(t.get("canonical"), f"{key}.canonical"),
                anchor_canonical=ck.canonical_joint(anchor.get("canonical"), f"{key}.anchor.canonical"),
                anchor_body=ck.string(anchor.get("body"), f"{key}.anchor.body"),
                position_cost=ck.number(t.get("position_cost", 1.0), f"{key}.position_cost"),
                orientation_cost=ck.number(t.get("orientation_cost", 0.0), f"{key}.orientation_cost"),
            )
        )
    iterations = ik.get("iterations", 3)
    if not isinstance(iterations, int) or isinstance(iterations, bool) or iterations < 1:
        ck.fail("ik.iterations", f"must be a positive integer, got {clip_value(iterations)}")
    return IKConfig(
        joints=tuple(names),
        root_canonical=root_canonical,
        root_body=root_body,
        tasks=tuple(tasks),
        axes=_parse_axes(ck, ik.get("axes", ["z", "x", "y"]), "ik.axes"),
        scale=ck.number(ik.get("scale", 1.0), "ik.scale", positive=True),
        posture_cost=ck.number(ik.get("posture_cost", 1e-3), "ik.posture_cost"),
        iterations=iterations,
        damping=ck.number(ik.get("damping", 1e-3), "ik.damping"),
        solver=ck.string(ik.get("solver", "daqp"), "ik.solver"),
    )


def resolve_model(ck: Checker, value: Any, base: Path | None) -> Path | None:
    """A model is a path (relative to the YAML, else to convodrive.sims) or {package, path}."""
    if value is None:
        return None
    if isinstance(value, dict):
        ck.keys(value, ("package", "path"), "model")
        package = ck.string(value.get("package"), "model.package")
        rel = ck.string(value.get("path"), "model.path")
        try:
            root = importlib.resources.files(package)
        except ModuleNotFoundError:
            ck.fail("model.package", f"package {clip_value(package)} is not installed")
        path = Path(str(root.joinpath(rel)))
        if not path.is_file():
            ck.fail("model.path", f"{clip_value(rel)} not found in package {clip_value(package)}")
        return path
    rel = ck.string(value, "model")
    candidates = [Path(rel).expanduser()]
    if base is not None and not Path(rel).is_absolute():
        candidates.insert(0, base / rel)
    candidates.append(Path(str(importlib.resources.files("convodrive.sims").joinpath(rel))))
    for path in candidates:
        if path.is_file():
            return path.resolve()
    ck.fail("model", f"MJCF {clip_value(rel)} not found beside the profile nor in convodrive.sims")
    return None
