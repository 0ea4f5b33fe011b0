"""ONNX Runtime sessions with explicit threads, on the CPU or the CUDA provider.

By default ONNX Runtime takes one intra-op thread per core and spins between runs; a run with a
generator, a renderer and MuJoCo on two cores would then fight over them. So every session here
says how many threads it uses (default 1) and whether it may spin (default no).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from convodrive.plumbing.errors import InputFileError, UserError

DEVICES = ("auto", "cpu", "cuda")


def _ort() -> Any:
    try:
        import onnxruntime
    except ImportError:
        raise UserError("learned models need onnxruntime (pip install 'convodrive[neural]')") from None
    return onnxruntime


def available_devices() -> list[str]:
    """``cpu``, plus ``cuda`` when this onnxruntime build has the CUDA provider."""
    providers = _ort().get_available_providers()
    return ["cpu"] + (["cuda"] if "CUDAExecutionProvider" in providers else [])


@dataclasses.dataclass(frozen=True)
class SessionOptions:
    threads: int = 1
    """Intra-op threads; inter-op is always 1 (graphs run their nodes in order)."""
    spinning: bool = False
    """Let idle threads spin: a little lower latency, a whole core burnt per thread."""
    device: str = "auto"
    """``cpu``, ``cuda``, or ``auto``: CUDA when the provider is present, else the CPU."""

    def __post_init__(self) -> None:
        if self.threads < 1:
            raise UserError(f"threads must be at least 1, got {self.threads}")
        if self.device not in DEVICES:
            raise UserError(f"device must be one of {', '.join(DEVICES)}, got {self.device!r}")

    def providers(self) -> list[str]:
        devices = available_devices()
        if self.device == "cuda" and "cuda" not in devices:
            raise UserError("device 'cuda' asked for, but this onnxruntime has no CUDA provider")
        if self.device in ("cuda", "auto") and "cuda" in devices:
            return ["CUDAExecutionProvider", "CPUExecutionProvider"]
        return ["CPUExecutionProvider"]


class Graph:
    """One ONNX graph in a session: ``graph(x=...)`` returns its outputs by name."""

    def __init__(self, path: str | Path, options: SessionOptions | None = None) -> None:
        ort = _ort()
        options = options or SessionOptions()
        so = ort.SessionOptions()
        so.intra_op_num_threads = options.threads
        so.inter_op_num_threads = 1
        so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        spin = "1" if options.spinning else "0"
        so.add_session_config_entry("session.intra_op.allow_spinning", spin)
        so.add_session_config_entry("session.inter_op.allow_spinning", spin)
        so.log_severity_level = 3
        self.path = Path(path)
        try:
            self.session = ort.InferenceSession(str(path), sess_options=so, providers=options.providers())
        except Exception as exc:  # onnxruntime raises its own exception types for a bad file
            raise InputFileError(path, f"ONNX Runtime cannot load it ({str(exc).splitlines()[0][:200]})") from None
        self.input_names = [i.name for i in self.session.get_inputs()]
        self.output_names = [o.name for o in self.session.get_outputs()]

    @property
    def providers(self) -> list[str]:
        return list(self.session.get_providers())

    def __call__(self, inputs: Mapping[str, np.ndarray] | None = None, **named: np.ndarray) -> dict[str, np.ndarray]:
        feed = {**(inputs or {}), **named}
        missing = [n for n in self.input_names if n not in feed]
        if missing:
            raise ValueError(f"{self.path.name}: missing inputs {missing}")
        outputs = self.session.run(self.output_names, {n: feed[n] for n in self.input_names})
        return dict(zip(self.output_names, outputs))
