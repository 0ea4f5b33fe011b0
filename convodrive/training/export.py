"""``convodrive export CHECKPOINT --out MODEL_DIR [--int8]``: a checkpoint to an ONNX model folder.

Each graph a recipe names is exported with the dynamo exporter and dynamic axes, then run in ONNX
Runtime against torch at every parity size (exporters can silently bake an example's shape into
a graph; a size it was not traced at shows that). A graph off by more than the tolerance stops the
export. ``--int8`` quantises the MatMul nodes of each graph dynamically (weights int8, activations
quantised at run time; convolutions stay float, as quantised convs can be far slower on a CPU)
and measures what that costs against the float graph; ``--float GRAPH,...`` keeps the named graphs
float in an int8 folder, for a model whose int8 cost sits in a few graphs (a diffusion denoiser's
step, whose error compounds over the sampling steps) and whose float size is too large to ship.
The folder is written beside its destination and renamed into place, so it is complete or absent.
"""

from __future__ import annotations

import contextlib
import dataclasses
import inspect
import io
import json
import logging
import subprocess
import tempfile
import warnings
from collections.abc import Callable, Collection, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from convodrive.neural.folder import MODEL_FORMAT, MODEL_FORMAT_VERSION, MODEL_JSON, sha256_file
from convodrive.neural.session import Graph, SessionOptions
from convodrive.plumbing.atomic import atomic_folder
from convodrive.plumbing.errors import InputFileError, UserError
from convodrive.training.checkpoint import Checkpoint, load_checkpoint, load_weights
from convodrive.training.model_card import model_card
from convodrive.training.recipe import DataSpec, GraphSpec, Recipe
from convodrive.training.registry import get_recipe

PARITY_TOLERANCE = 1e-4
OPSET = 18


@dataclasses.dataclass
class ExportResult:
    folder: Path
    parity: dict[str, dict[str, float]]
    int8: dict[str, dict[str, float]] | None


def restore(checkpoint: str | Path) -> tuple[Checkpoint, Recipe, Any, DataSpec, torch.nn.Module]:
    """The checkpoint's recipe, model config, data spec and network with its weights, in eval mode.
    A ``state.json`` this version cannot build a network from is one ``InputFileError`` naming it."""
    ckpt = load_checkpoint(checkpoint)
    state_path = ckpt.path / "state.json"
    try:
        recipe = get_recipe(ckpt.state["recipe"])
        config = recipe.model_config(ckpt.state["model_config"])
    except UserError as exc:
        raise InputFileError(state_path, str(exc)) from None
    stage = ckpt.state["stage"]
    if stage not in recipe.stages:
        raise InputFileError(state_path, f"names stage '{stage}', which model '{recipe.name}' does not have")
    spec = ckpt.data_spec()
    try:
        net = recipe.build_model(config, spec, stage)
    except UserError as exc:
        raise InputFileError(state_path, str(exc)) from None
    except (KeyError, IndexError, TypeError, ValueError, RuntimeError) as exc:
        raise InputFileError(
            state_path, f"describes no network this version builds ({type(exc).__name__}: {exc})"
        ) from None
    load_weights(net, ckpt)
    net.eval()
    return ckpt, recipe, config, spec, net


@contextlib.contextmanager
def _quiet() -> Any:
    """The exporter prints progress and warnings meant for its developers; keep a user's terminal clean."""
    loggers = [
        logging.getLogger(n) for n in ("", "torch.onnx", "torch.export", "torch._dynamo", "onnxscript", "torch.fx")
    ]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
            warnings.simplefilter("ignore")
            yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def export_graph(spec: GraphSpec, path: Path, trace_size: int = 5) -> None:
    example = spec.example(trace_size, np.random.default_rng(0))
    dims: dict[str, Any] = {}

    def dim(text: str) -> Any:
        """``name``, or ``k*name`` for an axis that is always a multiple of k (a network that
        downsamples by k), which the exporter must know to prove that its strided shapes agree."""
        factor, _, name = text.rpartition("*")
        base = dims.setdefault(name, torch.export.Dim(name, min=1, max=1 << 20))
        return int(factor) * base if factor else base

    per_input = [
        {a: dim(d) for a, d in axes.items()} if (axes := spec.dynamic.get(n)) else None for n in spec.input_names
    ]
    params = inspect.signature(spec.module.forward).parameters.values()
    varargs = next((p.name for p in params if p.kind is p.VAR_POSITIONAL), None)  # a GraphModule's
    dynamic_shapes = {varargs: tuple(per_input)} if varargs else dict(zip(spec.input_names, per_input))
    with _quiet(), torch.no_grad():
        torch.onnx.export(
            spec.module,
            example,
            str(path),
            input_names=list(spec.input_names),
            output_names=list(spec.output_names),
            dynamo=True,
            dynamic_shapes=dynamic_shapes,
            opset_version=OPSET,
            external_data=False,
            optimize=True,
        )


def _torch_outputs(spec: GraphSpec, inputs: tuple[torch.Tensor, ...]) -> list[np.ndarray]:
    with torch.no_grad():
        out = spec.module(*inputs)
    outs = out if isinstance(out, (tuple, list)) else (out,)
    return [o.detach().cpu().numpy() for o in outs]


def parity(spec: GraphSpec, path: Path, sizes: tuple[int, ...] | None = None, seed: int = 1) -> dict[str, float]:
    """Max abs error of ONNX Runtime against torch at each size, keyed ``size=N``."""
    graph = Graph(path, SessionOptions(threads=1, device="cpu"))
    result = {}
    rng = np.random.default_rng(seed)
    for size in sizes or spec.parity_sizes:
        inputs = spec.example(size, rng)
        expected = _torch_outputs(spec, inputs)
        try:
            got = graph({n: t.detach().cpu().numpy() for n, t in zip(spec.input_names, inputs)})
        except Exception as exc:  # onnxruntime's own error types: a shape the graph refuses
            first = str(exc).splitlines()[0][:160]
            raise UserError(
                f"export of graph '{spec.name}': ONNX Runtime rejects size {size}, a shape baked in at export? ({first})"
            ) from None
        errs = []
        for name, want in zip(spec.output_names, expected):
            if got[name].shape != want.shape:
                raise UserError(
                    f"export of graph '{spec.name}': output {name} has shape {got[name].shape} at size {size}, torch gives {want.shape}"
                )
            errs.append(float(np.max(np.abs(got[name].astype(np.float64) - want))) if want.size else 0.0)
        result[f"size={size}"] = max(errs)
    return result


def quantise_int8(src: Path, dst: Path, float_from: Sequence[str] = ()) -> None:
    """Dynamic int8 of every matrix product but the first ones each input of ``float_from`` reaches.
    Dynamic quantisation gives an activation one scale over the whole tensor: over a window of
    normalised motion, whose rare channels (a blink, tongueOut) reach ten standard deviations, that
    scale leaves the face's small movements a step or two (refiner, test split: FD_g face 0.97 in
    float, 1.26 in int8, with the motion's input projection in float 1.07)."""
    from onnxruntime.quantization import QuantType, quantize_dynamic

    keep = first_products(src, float_from) if float_from else []
    with _quiet():
        quantize_dynamic(
            str(src), str(dst), op_types_to_quantize=["MatMul"], weight_type=QuantType.QInt8, nodes_to_exclude=keep
        )


def first_products(path: Path, inputs: Sequence[str]) -> list[str]:
    """Names of the MatMul nodes that the values of ``inputs`` reach first, through any other nodes."""
    import onnx

    graph = onnx.load(str(path)).graph
    consumers: dict[str, list[onnx.NodeProto]] = {}
    for node in graph.node:
        for name in node.input:
            consumers.setdefault(name, []).append(node)
    found: list[str] = []
    seen: set[str] = set()
    frontier = list(inputs)
    while frontier:
        for node in consumers.get(frontier.pop(), []):
            if node.name in seen:
                continue
            seen.add(node.name)
            if node.op_type == "MatMul":
                found.append(node.name)
            elif node.op_type not in ("Shape", "Size"):  # those pass on the size, not the values
                frontier.extend(node.output)
    return found


def int8_cost(spec: GraphSpec, float_path: Path, int8_path: Path, seed: int = 2) -> dict[str, float]:
    """How far the int8 graph's outputs land from the float graph's, on the parity inputs."""
    fg, qg = (Graph(p, SessionOptions(threads=1, device="cpu")) for p in (float_path, int8_path))
    rng = np.random.default_rng(seed)
    abs_err, ref_sq, err_sq = 0.0, 0.0, 0.0
    for size in spec.parity_sizes:
        feed = {n: t.numpy() for n, t in zip(spec.input_names, spec.example(size, rng))}
        a, b = fg(feed), qg(feed)
        for name in spec.output_names:
            d = b[name].astype(np.float64) - a[name]
            abs_err = max(abs_err, float(np.abs(d).max()) if d.size else 0.0)
            err_sq += float((d**2).sum())
            ref_sq += float((a[name].astype(np.float64) ** 2).sum())
    return {"max_abs_err": abs_err, "relative_rms_err": float(np.sqrt(err_sq / max(ref_sq, 1e-30)))}


def _git_commit() -> str:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10, cwd=Path(__file__).parent
        )
        return out.stdout.strip() if out.returncode == 0 else "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _prepare_destination(out: Path) -> None:
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not (out / MODEL_JSON).exists())):
        raise UserError(f"--out {out}: exists and is not a model folder; choose a new or empty folder")


GraphExporter = Callable[[GraphSpec, Path], None]
"""Writes one graph's ONNX file; ``export_graph`` unless a caller has reason for another."""


def export_model(
    checkpoint: str | Path,
    out: str | Path,
    int8: bool = False,
    tolerance: float = PARITY_TOLERANCE,
    keep_float: Collection[str] = (),
    exporter: GraphExporter | None = None,
) -> ExportResult:
    """``keep_float``: with ``int8``, the graphs that stay float. ``exporter``: the tests' folders,
    whose graphs only need the runtime's contract (names, axes, parity), pass a faster one."""
    out = Path(out)
    if keep_float and not int8:
        raise UserError("--float names the graphs an int8 export keeps float: it needs --int8")
    ckpt, recipe, config, spec, net = restore(checkpoint)
    _prepare_destination(out)
    stage = ckpt.state["stage"]
    graphs = list(recipe.export_graphs(net, config, spec, stage))
    unknown = sorted(set(keep_float) - {g.name for g in graphs})
    if unknown:
        raise UserError(
            f"--float {','.join(unknown)}: no such graph in {recipe.name}'s {stage} export "
            f"(graphs: {', '.join(g.name for g in graphs)})"
        )
    with atomic_folder(out) as tmp:
        exported = _GraphsReport(exporter or export_graph)
        for g in graphs:
            exported.add(g, tmp, tolerance, int8 and g.name not in keep_float)
        for name, arrays in recipe.export_arrays(net, config, spec).items():
            np.savez(tmp / name, **arrays)
        meta = _model_meta(ckpt, recipe, spec, exported, tolerance, int8, keep_float)
        meta["files"] = {p.name: sha256_file(p) for p in sorted(tmp.iterdir()) if p.is_file()}
        (tmp / MODEL_JSON).write_text(json.dumps(meta, indent=2), encoding="utf-8")
        (tmp / "MODEL_CARD.md").write_text(model_card(recipe, config, spec, meta), encoding="utf-8")
    return ExportResult(out, exported.parity, exported.int8 or None)


@dataclasses.dataclass
class _GraphsReport:
    """The graphs exported so far: each one's parity, int8 cost and entry in model.json."""

    exporter: GraphExporter
    parity: dict[str, dict[str, float]] = dataclasses.field(default_factory=dict)
    int8: dict[str, dict[str, float]] = dataclasses.field(default_factory=dict)
    meta: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)

    def add(self, g: GraphSpec, folder: Path, tolerance: float, quantise: bool) -> None:
        """Export ``g`` into ``folder``, check its parity, quantise it if asked."""
        float_path = folder / f"{g.name}.onnx"
        self.exporter(g, float_path)
        self.parity[g.name] = parity(g, float_path)
        worst = max(self.parity[g.name].values())
        if not worst <= tolerance:
            raise UserError(
                f"export of graph '{g.name}' failed the parity check: ONNX Runtime differs from torch by {worst:.3g} (> {tolerance:g}) at {self.parity[g.name]}"
            )
        file = float_path.name
        if quantise:
            q_path = folder / f"{g.name}.int8.onnx"
            quantise_int8(float_path, q_path, g.float_from)
            self.int8[g.name] = int8_cost(g, float_path, q_path)
            float_path.unlink()
            file = q_path.name
        self.meta[g.name] = {
            "file": file,
            "inputs": list(g.input_names),
            "outputs": list(g.output_names),
            "dynamic_axes": {n: {str(a): d for a, d in axes.items()} for n, axes in g.dynamic.items()},
            "description": g.description,
        }


FOLDER_SETTINGS = ("vq_decoder_from", "refiner_teacher")
"""Settings that name a model folder a run learnt from: model.json gives the folder's name only."""


def _folder_name(key: str, value: Any) -> Any:
    return Path(value).name if key in FOLDER_SETTINGS and value else value


def _model_meta(
    ckpt: Checkpoint,
    recipe: Recipe,
    spec: DataSpec,
    exported: _GraphsReport,
    tolerance: float,
    int8: bool,
    keep_float: Collection[str],
) -> dict[str, Any]:
    """model.json, but for its file hashes."""
    return {
        "format": MODEL_FORMAT,
        "version": MODEL_FORMAT_VERSION,
        "model": recipe.name,
        "preset": ckpt.state["preset"],
        "stage": ckpt.state["stage"],
        "architecture": {k: _folder_name(k, v) for k, v in ckpt.state["model_config"].items()},
        "features": spec.info,
        "training": {
            "corpus": Path(str(ckpt.state.get("corpus"))).name,
            "steps": ckpt.step,
            "train_config": ckpt.state.get("train_config"),
            "world_size": ckpt.state.get("world_size"),
            "validation": ckpt.state.get("validation", {}),
            "checkpoint": ckpt.path.name,  # a folder name: a model folder names no path of the machine
            "commit": _git_commit(),
            "torch": torch.__version__,
        },
        "graphs": exported.meta,
        "parity": {"tolerance": tolerance, "max_abs_err": exported.parity},
        "int8": {"quantised": "MatMul, dynamic", "cost": exported.int8, "float": sorted(keep_float)} if int8 else None,
    }


def export_untrained(
    model: str,
    spec: DataSpec,
    out: str | Path,
    preset: str | None = None,
    stage: str | None = None,
    int8: bool = False,
    seed: int = 0,
    exporter: GraphExporter | None = None,
) -> ExportResult:
    """A model folder of freshly initialised weights (the last stage unless ``stage``), for
    benchmarks of speed, which the weights do not change, and for tests; ``spec`` stands in for a
    corpus."""
    from convodrive.training.checkpoint import save_checkpoint
    from convodrive.training.config import to_dict
    from convodrive.training.registry import get_preset

    recipe = get_recipe(model)
    preset_name, chosen = get_preset(recipe, preset)
    stage = stage or recipe.stages[-1]
    config = recipe.model_config(chosen.model)
    torch.manual_seed(seed)
    net = recipe.build_model(config, spec, stage)
    state = {
        "recipe": recipe.name,
        "preset": preset_name,
        "stage": stage,
        "model_config": to_dict(config),
        "train_config": to_dict(recipe.train_config(chosen.train)),
        "step": 0,
        "corpus": None,
        "world_size": 1,
        "validation": {},
        "torch": torch.__version__,
    }
    with tempfile.TemporaryDirectory(prefix="untrained-") as tmp:
        checkpoint = save_checkpoint(Path(tmp), net, torch.optim.AdamW(net.parameters()), spec, state)
        return export_model(checkpoint, out, int8=int8, exporter=exporter)
