"""Running the crop CNN (§3.3): on ONNX Runtime when it is installed, on torch otherwise.

torch's eager CPU kernels run EfficientNet-Lite0's batch norms, ReLU6 and TF-style "same"
paddings as separate passes over memory; ONNX Runtime folds them into the convolutions and runs
the same network about 2.5x faster on one CPU thread (``benchmarks/bench_classify.py``). The
network is exported from torch into memory the first time it runs (about 1 s of CPU per process);
nothing is written or downloaded. Its outputs match torch's to about 5e-5 (embeddings) and 1e-5
(probabilities); torch stays the reference, and the fallback when ``onnxruntime`` (or ``onnx``,
which torch's exporter needs) is not importable.

The environment variable ``GUARDRAIL_CNN_RUNTIME`` (``auto``, ``onnxruntime`` or ``torch``) picks
the runtime of a process (the workers of an embedded Dask cluster inherit it; set it where the
workers of another cluster run); ``auto``, the default, takes ONNX Runtime when it can.
"""

from __future__ import annotations

import importlib.util
import io
import os
import threading
import warnings
from collections.abc import Iterator
from typing import Any

import numpy as np
import torch
from torch import nn

from guardrail_core.errors import InvalidOptionError, ModelError
from guardrail_core.progress import progress_bar

RUNTIMES = ("auto", "onnxruntime", "torch")
RUNTIME_ENV = "GUARDRAIL_CNN_RUNTIME"
#: Crops per call of the network. ~8-64 run equally fast on ONNX Runtime; torch's eager kernels
#: slow down past ~16 (a batch's feature maps no longer fit the CPU's cache).
BATCH_SIZE = 16
_OPSET = 17


def batches(n: int, batch_size: int, *, progress: bool, desc: str) -> Iterator[slice]:
    """Consecutive slices of at most ``batch_size`` over ``range(n)``, with a progress bar."""
    if (
        isinstance(batch_size, bool)
        or not isinstance(batch_size, int | np.integer)
        or batch_size < 1
    ):
        raise InvalidOptionError(
            f"batch_size: expected a positive whole number, got {batch_size!r}"
        )
    with progress_bar(total=n, desc=desc, unit="crop", enabled=progress, leave=False) as bar:
        for start in range(0, n, batch_size):
            stop = min(start + batch_size, n)
            yield slice(start, stop)
            bar.update(stop - start)


def onnx_runtime_installed() -> bool:
    """Whether ONNX Runtime and the ``onnx`` package (torch's exporter needs it) import."""
    return all(importlib.util.find_spec(name) is not None for name in ("onnxruntime", "onnx"))


def chosen_runtime(requested: str | None = None) -> str:
    """``"onnxruntime"`` or ``"torch"``: ``requested`` or else ``$GUARDRAIL_CNN_RUNTIME``; ``auto``
    (the default) takes ONNX Runtime when installed.

    Raises :class:`InvalidOptionError` for a name not in :data:`RUNTIMES`, and
    :class:`ModelError` when ``onnxruntime`` is asked for and not installed.
    """
    name = requested if requested is not None else os.environ.get(RUNTIME_ENV, "auto")
    if name not in RUNTIMES:
        source = "runtime" if requested is not None else RUNTIME_ENV
        raise InvalidOptionError(f"{source}: expected one of {', '.join(RUNTIMES)}, got {name!r}")
    if name == "auto":
        return "onnxruntime" if onnx_runtime_installed() else "torch"
    if name == "onnxruntime" and not onnx_runtime_installed():
        raise ModelError(
            "the CNN runtime onnxruntime was asked for and is not installed: expected the "
            "packages onnxruntime and onnx (pip install onnxruntime onnx)"
        )
    return name


def export_onnx(module: nn.Module, input_size: int) -> bytes:
    """``module`` ((B, S, S, 3) uint8 -> (B, ...) float32, S = ``input_size``) as an ONNX model
    with a free batch size, in memory."""
    example = torch.zeros((2, input_size, input_size, 3), dtype=torch.uint8)
    buffer = io.BytesIO()
    with torch.no_grad(), warnings.catch_warnings():
        # The TorchScript exporter is deprecated (torch is pinned), and it notes the padding's
        # strided slices it leaves unfolded: neither is the user's business.
        warnings.simplefilter("ignore")
        torch.onnx.export(
            module,
            (example,),
            buffer,  # type: ignore[arg-type]  # the TorchScript exporter takes a binary file
            input_names=["crops"],
            output_names=["out"],
            dynamic_axes={"crops": {0: "batch"}, "out": {0: "batch"}},
            opset_version=_OPSET,
            dynamo=False,
        )
    return buffer.getvalue()


def _session(model: bytes, threads: int) -> Any:
    import onnxruntime

    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.execution_mode = onnxruntime.ExecutionMode.ORT_SEQUENTIAL
    options.graph_optimization_level = onnxruntime.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.log_severity_level = 3  # errors only
    # Threads that wait sleep: busy-waiting steals the core from the other worker.
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return onnxruntime.InferenceSession(model, options, providers=["CPUExecutionProvider"])


class CropNetwork:
    """A network over crops, (B, S, S, 3) uint8 -> (B, *out_shape) float32, run on ONNX Runtime
    or torch (:func:`chosen_runtime`).

    ONNX Runtime uses as many threads as torch is set to (``torch.set_num_threads``), so one
    setting governs both. The ONNX model is exported on the first call and kept; if the export
    fails and the runtime was chosen by ``auto``, the network warns and runs on torch.

    Parameters
    ----------
    module : torch module taking uint8 crops; put in eval mode (a module in training mode would
        be put back in it, children and all, by the exporter)
    input_size : S, px
    out_shape : the shape of one crop's output, e.g. ``(1280,)`` or ``()``
    runtime : ``auto``, ``onnxruntime`` or ``torch``; None: ``$GUARDRAIL_CNN_RUNTIME``
    """

    def __init__(
        self,
        module: nn.Module,
        input_size: int,
        out_shape: tuple[int, ...],
        *,
        runtime: str | None = None,
    ) -> None:
        self.module = module.eval()
        self.input_size = int(input_size)
        self.out_shape = tuple(out_shape)
        self.runtime = chosen_runtime(runtime)
        self._auto = (runtime or os.environ.get(RUNTIME_ENV, "auto")) == "auto"
        self._onnx: bytes | None = None
        self._sessions: dict[int, Any] = {}
        self._lock = threading.Lock()

    def __repr__(self) -> str:
        return f"CropNetwork(runtime={self.runtime!r}, input_size={self.input_size})"

    def __getstate__(self) -> dict[str, Any]:
        # Sessions and locks do not pickle or copy; the exported model does.
        return {k: v for k, v in self.__dict__.items() if k not in ("_sessions", "_lock")}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._sessions = {}
        self._lock = threading.Lock()

    def __call__(
        self,
        crops: np.ndarray,
        *,
        batch_size: int = BATCH_SIZE,
        progress: bool = False,
        desc: str = "running the CNN",
    ) -> np.ndarray:
        """The network's (N, *out_shape) float32 output for (N, S, S, 3) uint8 crops (checked by
        the caller)."""
        out = np.empty((len(crops), *self.out_shape), np.float32)
        for sl in batches(len(crops), batch_size, progress=progress, desc=desc):
            batch = np.ascontiguousarray(crops[sl])
            session = self._session() if self.runtime == "onnxruntime" else None
            if session is None:
                with torch.inference_mode():
                    out[sl] = self.module(torch.from_numpy(batch)).numpy()
            else:
                out[sl] = session.run(None, {"crops": batch})[0]
        return out

    def _session(self) -> Any:
        """The ONNX Runtime session for torch's thread count (made on first use); None when the
        export failed and the network fell back to torch."""
        threads = torch.get_num_threads()
        session = self._sessions.get(threads)
        if session is not None:
            return session
        with self._lock:
            if self._onnx is None:
                try:
                    self._onnx = export_onnx(self.module, self.input_size)
                except Exception as exc:  # the exporter's errors are of many kinds
                    if not self._auto:
                        raise ModelError(
                            f"cannot export the CNN to ONNX: {type(exc).__name__}: {exc}; "
                            f"set {RUNTIME_ENV}=torch to run it on torch"
                        ) from exc
                    warnings.warn(
                        f"cannot export the CNN to ONNX ({type(exc).__name__}: {exc}); running "
                        "it on torch",
                        RuntimeWarning,
                        stacklevel=3,
                    )
                    self.runtime = "torch"
                    return None
            return self._sessions.setdefault(threads, _session(self._onnx, threads))
