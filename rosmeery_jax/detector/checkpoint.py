"""Loading detector weights: our own state dicts and official YOLO-v5 checkpoints, safely.

Our shipped format is a plain state dict saved by ``torch.save``: ``{"format":
"rosmeery-yolov5", "size", "names", "imgsz", "meta", "state_dict"}``, read with
``torch.load(weights_only=True)``; ``meta`` may name the int8 calibration's percentile
(``int8_percentile``).

Official checkpoints pickle whole model objects (classes from the YOLO-v5 repository). They
are read with an unpickler that never imports or runs their code: every class it names
becomes an inert placeholder that only records its pickled attributes, and tensors are kept.
The parameters are then gathered by walking ``_modules`` / ``_parameters`` / ``_buffers``.

Before either unpickler runs, the archive must be intact (see :func:`check_archive`): a
damaged length field would otherwise have it allocate whatever the damage says.
"""

from __future__ import annotations

import io
import pickle
import pickletools
import zipfile
from pathlib import Path

import torch

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.files import atomic_path
from rosmeery_jax.detector.yolo import YOLOv5

FORMAT = "rosmeery-yolov5"


class _Inert:
    """Stands in for any class or function a checkpoint pickles; keeps only its state.
    Calling it (a pickled ``__reduce__``) builds another inert object and runs nothing."""

    def __new__(cls, *args, **kwargs):
        return object.__new__(cls)

    def __init__(self, *args, **kwargs):
        pass

    def __setstate__(self, state):
        self.__dict__["_state"] = state


# Globals the checkpoint may name that are plain data (anything else becomes _Inert).
_ALLOWED = {
    ("collections", "OrderedDict"), ("torch._utils", "_rebuild_tensor_v2"),
    ("torch._utils", "_rebuild_parameter"), ("builtins", "set"), ("__builtin__", "set"),
    ("torch", "Size"), ("torch", "float16"), ("torch", "float32"),
}


class _SafeUnpickler(pickle.Unpickler):
    def find_class(self, module, name):
        if (module, name) in _ALLOWED:
            return super().find_class("builtins" if module == "__builtin__" else module, name)
        return type(name, (_Inert,), {"__module__": f"inert.{module}"})


def _safe_load(file, **kwargs):
    return _SafeUnpickler(file, **kwargs).load()


class _pickle_module:  # what torch.load expects of a pickle module: both entry points restricted
    Unpickler = _SafeUnpickler
    load = staticmethod(_safe_load)
    __name__ = "rosmeery_safe_pickle"


def _state(obj) -> dict:
    return obj.__dict__.get("_state", {}) if isinstance(obj, _Inert) else {}


def _gather(obj, prefix: str, out: dict) -> None:
    st = _state(obj)
    for group in ("_parameters", "_buffers"):
        for k, v in (st.get(group) or {}).items():
            if isinstance(v, torch.Tensor):
                out[prefix + k] = v.detach()
    for k, child in (st.get("_modules") or {}).items():
        _gather(child, f"{prefix}{k}.", out)


def check_archive(path: Path) -> None:
    """One clear error unless ``path`` is an intact zip archive: its first entry at byte 0
    (torch reads entries at their recorded offsets, so data before it shifts every read),
    every entry's CRC right, and every pickle in it well formed (no opcode claiming more
    bytes than the pickle holds). A damaged file then fails here, not in an unpickler that
    first allocates the gigabytes a damaged length asks for."""
    with open(path, "rb") as fh:
        if fh.read(4) != b"PK\x03\x04":
            raise InputError(str(path), "file", "damaged zip archive (data before its first entry)")
    try:
        with zipfile.ZipFile(path) as zf:
            bad = zf.testzip()
            if bad is not None:
                raise InputError(str(path), bad, "damaged entry (CRC mismatch)")
            for name in (n for n in zf.namelist() if n.endswith(".pkl")):
                for _ in pickletools.genops(io.BytesIO(zf.read(name))):
                    pass
    except InputError:
        raise
    except Exception as err:  # noqa: BLE001 - any failure to read a damaged archive is bad input
        raise InputError(str(path), "file", f"damaged zip archive ({type(err).__name__})") from None


def _read_official(path: Path) -> dict:
    """An official YOLO-v5 ``.pt``: ``{"state_dict", "names", "nc", "size"}`` without running
    pickled code. The size comes from the checkpoint's width multiple. Only :func:`load`
    calls it, after :func:`check_archive` passed for a zip file."""
    path = Path(path)
    if not zipfile.is_zipfile(path):
        # Legacy (pre-zip) torch files start with pickles torch reads before any hook of
        # ours: refused, so no path hands a file to an unrestricted unpickler.
        raise InputError(str(path), "file", "not a zip-format torch checkpoint (legacy or raw pickles are refused: "
                         "they can run code; re-save it with torch.save)")
    try:
        ckpt = torch.load(path, map_location="cpu", pickle_module=_pickle_module, weights_only=False)
    except Exception as err:  # noqa: BLE001 - any failure of a foreign file is bad input
        raise InputError(str(path), "file", f"not a readable torch checkpoint ({type(err).__name__})") from None
    model = ckpt.get("ema") or ckpt.get("model") if isinstance(ckpt, dict) else None
    if model is None:
        raise InputError(str(path), "model", "no model in this checkpoint")
    sd: dict = {}
    _gather(model, "", sd)
    if not sd:
        raise InputError(str(path), "model", "holds no YOLO-v5 parameters")
    st = _state(model)
    names = st.get("names")
    names = [names[i] for i in sorted(names)] if isinstance(names, dict) else list(names or [])
    yaml = st.get("yaml") or {}
    width = float(yaml.get("width_multiple", 0.25))
    size = {0.25: "n", 0.5: "s", 0.75: "m", 1.0: "l", 1.25: "x"}.get(width, "n")
    return {"state_dict": sd, "names": names, "nc": int(yaml.get("nc", len(names))), "size": size}


def _number(v, kind) -> bool:
    return isinstance(v, kind) and not isinstance(v, bool)


def _read_ours(path: Path, raw: dict) -> dict:
    """Our format's fields, each checked: a wrong one is an error naming it, not a
    traceback later in the detector."""
    def bad(field: str, why: str):
        return InputError(str(path), field, why)

    names, imgsz, meta = raw.get("names", []), raw.get("imgsz"), raw.get("meta") or {}
    if not isinstance(raw.get("state_dict"), dict):
        raise bad("state_dict", "missing")
    if not isinstance(names, (list, tuple)) or not names or not all(isinstance(n, str) for n in names):
        raise bad("names", "must be a list of one or more class names")
    if imgsz is not None and not (isinstance(imgsz, (list, tuple)) and len(imgsz) == 2
                                  and all(_number(v, int) and 0 < v <= 8192 for v in imgsz)):
        raise bad("imgsz", f"must be [height, width] in pixels, got {imgsz!r:.40}")
    if not isinstance(raw.get("size", "n"), str):
        raise bad("size", "must be a YOLO-v5 size letter (n, s, m, l, x)")
    if not isinstance(meta, dict):
        raise bad("meta", "must be a mapping")
    percentile = meta.get("int8_percentile")
    if percentile is not None and not (_number(percentile, (int, float)) and 0 < percentile <= 100):
        raise bad("meta.int8_percentile", f"must be a percentage in (0, 100], got {percentile!r:.40}")
    return {"state_dict": raw["state_dict"], "names": list(names), "nc": len(names), "size": raw.get("size", "n"),
            "imgsz": None if imgsz is None else list(imgsz),
            "int8_percentile": None if percentile is None else float(percentile)}


def load(path: str | Path, device: str = "cpu"):
    """A ready :class:`~rosmeery_jax.detector.yolo.YOLOv5` (eval mode, float32) from our
    state-dict format or an official checkpoint; one clear error for anything else."""
    path = Path(path)
    if not path.is_file():
        raise InputError(str(path), "file", "not found")
    raw = None
    if zipfile.is_zipfile(path):
        check_archive(path)
        try:  # torch's weights-only unpickler: tensors and plain containers, nothing else
            raw = torch.load(path, map_location="cpu", weights_only=True)
        except Exception:  # noqa: BLE001 - not our format: maybe an official pickled checkpoint
            raw = None
    if isinstance(raw, dict) and raw.get("format") == FORMAT:
        info = _read_ours(path, raw)
    else:
        info = _read_official(path)
    p2 = "model.31.anchors" in info["state_dict"]  # the yolov5-p2 graph's head is layer 31
    try:
        model = YOLOv5(info["nc"], info["size"], info["names"], p2)
    except ValueError as err:
        raise InputError(str(path), "size", str(err)) from None
    sd = {k: v.float() if v.is_floating_point() else v for k, v in info["state_dict"].items()}
    try:
        model.load_state_dict(sd, strict=True)
    except RuntimeError as err:
        first = str(err).splitlines()[1].strip() if len(str(err).splitlines()) > 1 else str(err)
        raise InputError(str(path), "state_dict", f"does not match YOLO-v5{info['size']}{'-p2' * p2} with "
                         f"{info['nc']} classes: {first[:160]}") from None
    model.imgsz = info.get("imgsz")  # the input size it was trained at
    model.int8_percentile = info.get("int8_percentile")  # its own int8 calibration, if it names one
    return model.eval().to(device)


def save(model, path: str | Path, imgsz: tuple[int, int], meta: dict | None = None) -> None:
    """Our format, fp16 parameters (BatchNorm counters stay integer), written atomically."""
    sd = {k: v.detach().half() if v.is_floating_point() else v.detach() for k, v in model.state_dict().items()}
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:  # a file object: torch names the archive's folder
        torch.save({"format": FORMAT, "size": model.size, "names": list(model.names), "imgsz": list(imgsz),
                    "meta": meta or {}, "state_dict": sd}, fh)  # "archive", not after the temporary file
