"""Where the detector's network runs: torch eager, or its exported ONNX graph in ONNX Runtime,
in float32 or quantised to int8.

Every runtime maps a batch (B, 3, H, W) float32 in [0, 1] to the decoded head (B, A, 5 + C):
box centre and size in pixels, objectness, class probabilities (A anchors over the three
strides, C classes). Non-maximum suppression is :mod:`rosmeery_jax.detector.boxes` (numpy), so
the runtimes differ only in the network's arithmetic (docs/detector.md gives the measured
speed and the mAP of each).

The ONNX graph is exported from the weights by ``torch.onnx.export`` at one fixed input shape
(the session's batch and padded frame), never downloaded: ``rosmeery detector export`` writes
it where asked, and a session builds it on first use into
``$XDG_CACHE_HOME/rosmeery-jax/detector/`` (``~/.cache/...``), named by the weights' content,
so other weights or another shape never reuse it; building one removes the graphs of the same
weights that an earlier :data:`EXPORT_VERSION` left there. The int8 graph is ONNX Runtime's
static quantisation of it (QDQ, int8 weights per channel, uint8 activations), its activation
ranges calibrated on frames rendered from procedural worlds (never the paper worlds the
detector is scored in): each range holds 99.99 % of the calibration's values, so a rare outlier
does not widen the int8 step of all the others.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import io
import logging
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.files import atomic_path

# ONNX Runtime (1.32 on Linux too) keeps a device id and an event store in the user's cache
# folder and uploads usage events unless this is set before it loads; a benchmark run writes
# nothing outside its own folders and sends nothing. Set it to 0 beforehand to opt back in.
os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")

RUNTIMES = ("torch", "onnxruntime", "onnxruntime-int8")
DEFAULT = "onnxruntime-int8"  # the fastest measured; its mAP cost is in docs/detector.md
# the packages each runtime needs (onnx and onnxscript export the graph)
_NEEDS = {"torch": ("torch",), "onnxruntime": ("onnxruntime", "onnx", "onnxscript"),
          "onnxruntime-int8": ("onnxruntime", "onnx", "onnxscript")}
EXPORT_VERSION = 2  # bump when the exported or quantised graph changes: old cached files are then not reused
# Calibration frames for int8: procedural worlds of all four kinds, none a paper world
CALIBRATION_WORLDS = ("procedural:apartment:2000", "procedural:office:2000", "procedural:kitchen:2000",
                      "procedural:lab:2000")
CALIBRATION_FRAMES = 128
CALIBRATION_PERCENTILE = 99.99  # the share of activation values each int8 range holds (docs/detector.md)


@dataclass(frozen=True)
class Calibration:
    """How the int8 graph's activation ranges are calibrated: on frames scaled up ``scale``
    times (as the network sees them), each range holding ``percentile`` % of the values.
    Weights may name their own percentile (``meta["int8_percentile"]``)."""

    scale: int = 1
    percentile: float = CALIBRATION_PERCENTILE

    @classmethod
    def of(cls, scale: int, percentile: float | None) -> "Calibration":
        """The calibration for frames scaled up ``scale`` times, at weights' own percentile
        if they name one (None: the default)."""
        return cls(scale) if percentile is None else cls(scale, percentile)

    def suffix(self) -> str:
        """The quantised graph's file suffix: the default calibration's is plain."""
        if self == Calibration():
            return ".int8.onnx"
        return f".x{self.scale}-p{self.percentile:g}.int8.onnx"


def padded(h: int, w: int) -> tuple[int, int]:
    """A frame's size padded to whole strides of 32, the network's input (H, W)."""
    return h + (-h) % 32, w + (-w) % 32


def upscale_factor(imgsz, h: int, w: int) -> int:
    """How many times frames of h x w are scaled up for weights trained at ``imgsz`` (H, W):
    the whole k > 1 with (k h, k w) == imgsz, otherwise 1 (the frames as they are)."""
    if not imgsz or imgsz[0] % h or imgsz[0] // h < 2 or imgsz[0] * w != imgsz[1] * h:
        return 1
    return imgsz[0] // h


def upscale(images: np.ndarray, k: int) -> np.ndarray:
    """Frames (I, H, W, 3) uint8 -> (I, k H, k W, 3) uint8: bilinear (torch's, half-pixel
    centres), rounded, in parts of 256 frames (a training set's float copy would not fit in
    memory at once); the frames themselves for k = 1."""
    if k == 1:
        return images
    import torch  # the detector extra: imported only when YOLO runs
    import torch.nn.functional as F

    images = np.require(images, np.uint8, ("C", "W"))  # writable: torch warns on read-only arrays
    out = np.empty((len(images), images.shape[1] * k, images.shape[2] * k, 3), np.uint8)
    for i in range(0, len(images), 256):
        # (I, H, W, 3) seen as (I, 3, H, W) in channels-last order: no copies around the
        # interpolation, twice as fast as contiguous channels, the same values (exact
        # multiples of 1/16 before rounding, for k = 2)
        x = torch.from_numpy(images[i:i + 256]).permute(0, 3, 1, 2).float()
        y = F.interpolate(x, scale_factor=k, mode="bilinear", align_corners=False)
        torch.from_numpy(out[i:i + 256]).permute(0, 3, 1, 2).copy_(y.round_())  # cast in place
    return out


INSTALL = "pip install 'rosmeery-jax[detector]' 'torch==2.13.0'"  # the detector extra, torch pinned


def require(source: str, where: str, modules: tuple[str, ...] = (), what: str = "", alternative: str = "") -> None:
    """Before any work: one line where ``where`` (of ``source``) needs packages of the
    detector extra that are not installed: torch and ``modules``. They are imported only
    when YOLO runs or is exported, and a missing one would otherwise end in a traceback."""
    lacking = [m for m in dict.fromkeys(("torch", *modules)) if importlib.util.find_spec(m) is None]
    if lacking:
        raise InputError(source, where, f"{what + ' ' if what else ''}needs {', '.join(lacking)} (the detector "
                         f"extra): {INSTALL}{alternative}")


def check(runtime: str, source: str = "config", where: str = "detector_runtime", what: str | None = None,
          alternative: str = "") -> None:
    """One line for an unknown runtime, or for one whose packages (torch and its own) are
    missing, named as :func:`require` names them (``what`` by default the runtime)."""
    if runtime not in RUNTIMES:
        raise InputError(source, "detector_runtime", f"unknown runtime {runtime!r}; one of {', '.join(RUNTIMES)}")
    require(source, where, _NEEDS[runtime], runtime if what is None else what, alternative)


def export(model, out: str | Path, batch: int, height: int, width: int) -> Path:
    """Write the ONNX graph of ``model`` (a YOLOv5 in eval mode) for inputs (batch, 3, height,
    width), decode included, as one self-contained file (atomically). Class names go into the
    file's metadata."""
    import torch  # exporting needs torch; running the file does not

    class Head(torch.nn.Module):  # what the exporter traces: forward() must be the decoded head
        def __init__(self, net):
            super().__init__()
            self.net = net

        def forward(self, x):
            return self.net.decoded(x)

    x = torch.zeros(batch, 3, height, width)
    with _quiet():
        program = torch.onnx.export(Head(model.float().eval()), (x,), input_names=["images"], output_names=["pred"],
                                    dynamo=True, optimize=True, verbose=False)
    onnx = program.model_proto
    for key, value in (("names", "\n".join(model.names)), ("export_version", str(EXPORT_VERSION))):
        entry = onnx.metadata_props.add()
        entry.key, entry.value = key, value
    with atomic_path(out) as tmp:
        tmp.write_bytes(onnx.SerializeToString())
    return Path(out)


def cached_export(weights: Path, batch: int, height: int, width: int, int8: bool = False,
                  calibration: Calibration = Calibration()) -> Path:
    """The ONNX graph of ``weights`` at this shape (int8: quantised as ``calibration``
    says), from the cache or built into it now."""
    digest = hashlib.sha256(Path(weights).read_bytes()).hexdigest()[:20]
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "rosmeery-jax" / "detector"
    path = base / f"{digest}-v{EXPORT_VERSION}-b{batch}-{height}x{width}.onnx"
    if not path.is_file():
        from rosmeery_jax.detector import checkpoint  # imports torch

        export(checkpoint.load(weights), path, batch, height, width)
        for stale in base.glob(f"{digest}-v*.onnx"):  # these weights' graphs of an earlier version: never read again
            if not stale.name.startswith(f"{digest}-v{EXPORT_VERSION}-"):
                stale.unlink(missing_ok=True)
    if not int8:
        return path
    quantised = path.with_suffix(calibration.suffix())
    if not quantised.is_file():
        quantise(path, quantised, calibration_frames(height, width, calibration.scale), calibration.percentile)
    return quantised


def calibration_frames(height: int, width: int, scale: int = 1) -> np.ndarray:
    """(F, H, W, 3) uint8 frames of :data:`CALIBRATION_WORLDS` (the detector dataset's
    viewpoints), scaled up ``scale`` times and padded to height x width."""
    from rosmeery_jax.detector.dataset import DatasetConfig, generate

    cfg = DatasetConfig(worlds=CALIBRATION_WORLDS, per_world=CALIBRATION_FRAMES // len(CALIBRATION_WORLDS), seed=1)
    frames = np.stack([f[3] for f in generate(cfg, splits=("train", "val"), progress=False)])[:CALIBRATION_FRAMES]
    frames = upscale(frames, scale)
    out = np.full((len(frames), height, width, 3), 114, np.uint8)
    out[:, :frames.shape[1], :frames.shape[2]] = frames
    return out


def quantise(src: Path, out: Path, frames: np.ndarray, percentile: float = CALIBRATION_PERCENTILE) -> Path:
    """ONNX Runtime's static int8 quantisation of the graph ``src`` (QDQ), activation ranges
    from ``frames`` (F, H, W, 3) uint8 in batches of the graph's size; written atomically."""
    import onnxruntime as ort
    from onnxruntime.quantization import (
        CalibrationDataReader,
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quantize_static,
    )

    batch = ort.InferenceSession(str(src), providers=["CPUExecutionProvider"]).get_inputs()[0].shape[0]
    x = frames.transpose(0, 3, 1, 2).astype(np.float32) / np.float32(255)

    class Batches(CalibrationDataReader):
        def __init__(self):
            self.parts = iter([x[i:i + batch] for i in range(0, len(x) - batch + 1, batch)])

        def get_next(self):
            return {"images": part} if (part := next(self.parts, None)) is not None else None

    with atomic_path(out) as tmp, _quiet():
        quantize_static(str(src), str(tmp), Batches(), quant_format=QuantFormat.QDQ, per_channel=True,
                        activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
                        nodes_to_exclude=_decode_nodes(src), calibrate_method=CalibrationMethod.Percentile,
                        extra_options={"CalibPercentile": percentile})
    return Path(out)


@contextlib.contextmanager
def _quiet():
    """Silence the exporter's and the quantiser's progress lines and advice (stdout, warnings,
    logging): a session's output stays its own."""
    level = logging.root.manager.disable
    logging.disable(logging.WARNING)
    try:
        with contextlib.redirect_stdout(io.StringIO()), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        logging.disable(level)


def _decode_nodes(path: Path) -> list[str]:
    """The graph's nodes after the head's three convolutions (the decode), kept in float: it
    joins pixel coordinates and probabilities in one tensor, which one int8 scale would ruin."""
    import onnx

    graph = onnx.load(str(path)).graph
    frontier = {o for n in graph.node if n.op_type == "Conv" and any(i.startswith("net.model.24.") for i in n.input)
                for o in n.output}
    excluded: list[str] = []
    for node in graph.node:  # topological order: a node's inputs come before it
        if frontier.intersection(node.input):
            excluded.append(node.name)
            frontier.update(node.output)
    return excluded


class TorchNetwork:
    """The YOLOv5 module itself, in torch eager."""

    def __init__(self, model):
        self.model = model

    def __call__(self, x: np.ndarray) -> np.ndarray:
        import torch

        with torch.inference_mode():
            return self.model.decoded(torch.from_numpy(x)).numpy()


class OnnxRuntimeNetwork:
    """An exported graph in ONNX Runtime's CPU provider, all graph optimisations on."""

    def __init__(self, path: Path, threads: int | None):
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads or 0  # 0: ONNX Runtime's default, one per core
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3  # errors only
        # No spinning after a run: its threads would wait busy while torch does the NMS
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self.session.run(None, {"images": x})[0]


def network(runtime: str, model, weights: Path, batch: int, height: int, width: int, threads: int | None = None,
            calibration: Calibration = Calibration()):
    """The network of ``model`` (loaded from ``weights``) on ``runtime``, for inputs (batch, 3,
    height, width); int8 calibrated as ``calibration`` says."""
    check(runtime)
    if runtime == "torch":
        return TorchNetwork(model)
    graph = cached_export(weights, batch, height, width, int8=runtime.endswith("int8"), calibration=calibration)
    return OnnxRuntimeNetwork(graph, threads)
