"""The detector's runtimes: the exported ONNX graph in ONNX Runtime gives torch's detections
(float32: equal to float rounding; int8: within the stated tolerance), built by our own
export, cached by the weights' content, and a missing runtime is one clear line."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

from rosmeery_jax.detector import runtime  # before ONNX Runtime loads: it sets ORT_DISABLE_TELEMETRY

pytest.importorskip("torch")
pytest.importorskip("onnxruntime")

from rosmeery_jax.core.errors import InputError  # noqa: E402
from rosmeery_jax.detector.boxes import box_iou  # noqa: E402
from rosmeery_jax.detector.detections import DEFAULT_WEIGHTS, YoloDetector  # noqa: E402


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """One cache folder for the module: each graph is exported (and quantised) once."""
    mp = pytest.MonkeyPatch()
    mp.setenv("XDG_CACHE_HOME", str(tmp_path_factory.mktemp("xdg")))
    yield
    mp.undo()


@pytest.fixture(scope="module")
def frames():
    """A fixed batch: 32 frames of the Small Office at the session's resolution (160 x 128)."""
    import jax
    import jax.numpy as jnp

    from rosmeery_jax.apps.bench import random_targets
    from rosmeery_jax.env import make
    from rosmeery_jax.raycast.sensors import rgb

    env = make("small_office")
    poses = jnp.asarray(random_targets(env.world, 32, 4))
    return np.asarray(jax.jit(jax.vmap(lambda p: rgb(env.rays, env.config.camera, p)))(poses)[0])


@pytest.fixture(scope="module")
def torch_detections(frames):
    out = YoloDetector((), runtime="torch").forward(frames)
    assert sum(len(d) for d in out) > 30  # not vacuous: the frames hold detections
    return out


def _matches(ref: list[np.ndarray], got: list[np.ndarray]):
    """Per detection of ``ref``: the best IoU with a same-class detection of ``got`` in the
    same frame, and the confidence difference to it; and how many of ``got`` match none."""
    ious, dconf, extra = [], [], 0
    for a, b in zip(ref, got):
        iou = box_iou(a[:, :4], b[:, :4]) * (a[:, None, 5] == b[None, :, 5]) if len(a) and len(b) \
            else np.zeros((len(a), len(b)))
        if len(a):
            best = iou.argmax(1) if len(b) else np.zeros(len(a), int)
            ious += list(iou.max(1) if len(b) else np.zeros(len(a)))
            dconf += list(np.abs(a[:, 4] - b[best, 4]) if len(b) else np.ones(len(a)))
        extra += int((iou.max(0) < 0.5).sum()) if len(a) and len(b) else len(b)
    return np.array(ious), np.array(dconf), extra


def test_onnxruntime_float32_detections_equal_torchs(cache, frames, torch_detections):
    got = YoloDetector((), runtime="onnxruntime").forward(frames)
    assert [len(d) for d in got] == [len(d) for d in torch_detections]
    for a, b in zip(torch_detections, got):
        np.testing.assert_array_equal(a[:, 5], b[:, 5])
        np.testing.assert_allclose(a[:, :4], b[:, :4], atol=1e-2)  # pixels
        np.testing.assert_allclose(a[:, 4], b[:, 4], atol=1e-4)


def test_onnxruntime_writes_nothing_outside_and_keeps_no_device_id(cache, tmp_path):
    """ONNX Runtime run through our runtime, in a fresh process with a fresh home and cache:
    nothing appears in either (ONNX Runtime's telemetry keeps a device id and an event store
    in the cache folder unless ORT_DISABLE_TELEMETRY is set before it loads)."""
    graph = runtime.cached_export(DEFAULT_WEIGHTS, 32, 128, 160)  # the other tests' graph
    home = tmp_path / "home"
    home.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "ORT_DISABLE_TELEMETRY"}
    env.update(HOME=str(home), XDG_CACHE_HOME=str(home / ".cache"))
    code = ("import sys, numpy as np; from rosmeery_jax.detector import runtime; "
            "net = runtime.OnnxRuntimeNetwork(sys.argv[1], 1); "
            "assert net(np.zeros((32, 3, 128, 160), np.float32)).shape[0] == 32")
    subprocess.run([sys.executable, "-c", code, str(graph)], env=env, check=True, cwd=tmp_path)
    assert not list(home.rglob("*"))


def test_int8_detections_match_torchs_within_the_stated_tolerance(cache, frames, torch_detections):
    """docs/detector.md: at least 90 % of torch's detections, and every one with a confidence
    of 0.5 or more, have an int8 one of the same class with IoU >= 0.6 and a confidence
    within 0.2; the median IoU is above 0.85; at most 15 % more detections than torch."""
    got = YoloDetector((), runtime="onnxruntime-int8").forward(frames)
    iou, dconf, extra = _matches(torch_detections, got)
    conf = np.concatenate([d[:, 4] for d in torch_detections])
    match = (iou >= 0.6) & (dconf <= 0.2)
    assert match.mean() >= 0.9 and match[conf >= 0.5].all()
    assert np.median(iou) > 0.85
    assert extra <= 0.15 * len(iou)


def test_the_export_is_cached_by_content_and_shape_and_quantised_the_same_twice(cache, tmp_path):
    first = runtime.cached_export(DEFAULT_WEIGHTS, 32, 128, 160, int8=True)
    assert runtime.cached_export(DEFAULT_WEIGHTS, 32, 128, 160, int8=True) == first  # reused
    digest = first.name.split("-v")[0]
    old = runtime.EXPORT_VERSION - 1
    stale = [first.with_name(f"{digest}-v{old}-b32-128x160{end}") for end in (".onnx", ".int8.onnx")]
    foreign = first.with_name(f"{'0' * len(digest)}-v{old}-b32-128x160.onnx")  # other weights'
    for path in stale + [foreign]:
        path.write_bytes(b"old")
    other = runtime.cached_export(DEFAULT_WEIGHTS, 8, 128, 160)
    assert other != first.with_suffix("").with_suffix(".onnx") and other.is_file()
    assert not any(path.exists() for path in stale) and foreign.exists() and first.is_file()  # an earlier version's go
    again = runtime.quantise(first.with_suffix("").with_suffix(".onnx"), tmp_path / "again.onnx",
                             runtime.calibration_frames(128, 160))
    assert again.read_bytes() == first.read_bytes()  # calibration and quantisation are deterministic


def test_export_command_writes_a_file_onnxruntime_runs_and_never_overwrites(cache, tmp_path, capsys):
    import onnxruntime as ort

    from rosmeery_jax.apps.cli import main

    out = tmp_path / "yolo.onnx"
    assert main(["detector", "export", "--out", str(out), "--batch", "2", "--size", "100x60"]) == 0
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    assert session.get_inputs()[0].shape == [2, 3, 64, 128]  # padded to whole strides of 32
    pred = session.run(None, {"images": np.zeros((2, 3, 64, 128), np.float32)})[0]
    assert pred.shape[0] == 2 and pred.shape[2] == 5 + 27
    before = out.read_bytes()
    assert main(["detector", "export", "--out", str(out)]) == 2  # exists: refused, kept
    assert out.read_bytes() == before and "never overwritten" in capsys.readouterr().err
    assert main(["detector", "export", "--out", str(tmp_path / "b.onnx"), "--size", "160"]) == 2
    assert "WxH" in capsys.readouterr().err and not (tmp_path / "b.onnx").exists()
    twice = tmp_path / "twice.onnx"  # weights trained on frames scaled up: the graph takes them so
    assert main(["detector", "export", "--weights", "procedural_2x", "--out", str(twice), "--batch", "1"]) == 0
    assert ort.InferenceSession(str(twice), providers=["CPUExecutionProvider"]).get_inputs()[0].shape == [1, 3, 256, 320]
    assert "scaled up 2 times" in capsys.readouterr().out


def test_frames_are_scaled_up_only_by_a_whole_factor_to_the_size_the_weights_were_trained_at():
    assert runtime.upscale_factor([256, 320], 128, 160) == 2
    assert runtime.upscale_factor([384, 480], 128, 160) == 3
    for imgsz in ([128, 160], None, [256, 300], [200, 250], [64, 80]):  # own size, unknown, other shape, smaller
        assert runtime.upscale_factor(imgsz, 128, 160) == 1
    row = np.array([[[0, 0, 0], [100, 200, 40]]], np.uint8)[None]  # one frame, 1 x 2 pixels
    up = runtime.upscale(row, 2)  # half-pixel centres: 0, 1/4, 3/4 and 1 of the way, edges held
    assert up.shape == (1, 2, 4, 3)
    np.testing.assert_array_equal(up[0, 0, :, 1], [0, 50, 150, 200])
    np.testing.assert_array_equal(up[0, 0], up[0, 1])
    assert runtime.upscale(row, 1) is row


def test_scaling_up_twice_is_exact_bilinear_rounded_half_to_even_on_any_frame():
    """Each pixel of a frame scaled up twice is (9 a + 3 b + 3 c + d) / 16 of its four
    nearest source pixels (edges held), rounded half to even (torch's round), on frames
    as the session passes them (read-only) or not."""
    frames = np.random.default_rng(3).integers(0, 256, (3, 7, 5, 3), dtype=np.uint8)
    frames.flags.writeable = False
    a = frames.astype(np.int64)
    near = lambda x, axis, d: np.take(x, np.clip(np.arange(x.shape[axis]) + d, 0, x.shape[axis] - 1), axis)  # noqa: E731
    rows = np.stack((3 * a + near(a, 1, -1), 3 * a + near(a, 1, 1)), 2).reshape(3, 14, 5, 3)
    sums = np.stack((3 * rows + near(rows, 2, -1), 3 * rows + near(rows, 2, 1)), 3).reshape(3, 14, 10, 3)
    want = np.round(sums / 16)  # numpy rounds half to even, as torch does
    assert ((sums % 16) == 8).any()  # ties present: the rounding rule is tested
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(runtime.upscale(frames, 2), want)


def test_weights_trained_at_twice_the_size_see_frames_scaled_up_and_box_in_the_frames_pixels(frames):
    import torch

    detector = YoloDetector((), runtime="torch")
    detector.model.imgsz = [256, 320]  # as weights trained on 160 x 128 frames scaled up twice
    got = detector.forward(frames[:8])
    x = torch.from_numpy(runtime.upscale(frames[:8], 2)).permute(0, 3, 1, 2).float() / 255
    ref = detector.model.detect(x)
    assert sum(len(d) for d in ref) > 5  # not vacuous
    for a, b in zip(ref, got):
        np.testing.assert_allclose(b[:, :4] * 2, a[:, :4], atol=1e-3)
        np.testing.assert_allclose(b[:, 4:], a[:, 4:], atol=1e-5)


def test_the_int8_graph_is_calibrated_on_frames_as_the_network_sees_them_at_the_weights_percentile(monkeypatch):
    seen = []
    monkeypatch.setattr(runtime, "network", lambda *args: seen.append(args[-1]) or object())
    assert YoloDetector((), "procedural_2x", runtime="onnxruntime-int8").prepare(128, 160) == (256, 320)
    assert YoloDetector((), "procedural", runtime="onnxruntime-int8").prepare(128, 160) == (128, 160)
    assert seen == [runtime.Calibration(2, 99.95), runtime.Calibration(1, runtime.CALIBRATION_PERCENTILE)]
    assert seen[1].suffix() == ".int8.onnx"  # the default's cached graphs keep their names
    assert seen[0].suffix() == ".x2-p99.95.int8.onnx"


def test_calibration_frames_are_scaled_up_as_the_network_sees_them_then_padded(monkeypatch):
    from rosmeery_jax.detector import dataset

    rng = np.random.default_rng(0)
    rendered = rng.integers(0, 256, (runtime.CALIBRATION_FRAMES, 30, 40, 3), dtype=np.uint8)
    monkeypatch.setattr(dataset, "generate", lambda cfg, **kw: ((None, None, None, f, None) for f in rendered))
    got = runtime.calibration_frames(64, 96, scale=2)
    assert got.shape == (runtime.CALIBRATION_FRAMES, 64, 96, 3)
    np.testing.assert_array_equal(got[:, :60, :80], runtime.upscale(rendered, 2))
    assert (got[:, 60:] == 114).all() and (got[:, :, 80:] == 114).all()  # the official grey pad


def test_a_stride_4_graph_exports_with_its_fourth_level_and_runs_as_in_torch(tmp_path):
    import onnxruntime as ort
    import torch

    from rosmeery_jax.detector.yolo import YOLOv5

    torch.manual_seed(0)
    model = YOLOv5(3, "n", ["a", "b", "c"], p2=True).eval()
    out = runtime.export(model, tmp_path / "p2.onnx", 2, 64, 96)
    x = torch.rand(2, 3, 64, 96)
    got = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"]).run(None, {"images": x.numpy()})[0]
    # (16 x 24 + 8 x 12 + 4 x 6 + 2 x 3) cells x 3 anchors: strides 4, 8, 16 and 32
    assert got.shape == (2, 3 * (384 + 96 + 24 + 6), 8)
    np.testing.assert_allclose(got, model.decoded(x).numpy(), atol=1e-4, rtol=1e-4)


def test_a_missing_or_unknown_runtime_is_one_clear_line(monkeypatch):
    with pytest.raises(InputError, match="unknown runtime 'tensorrt'"):
        runtime.check("tensorrt")
    found = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "onnxscript" else found(name, *a))
    with pytest.raises(InputError, match=r"onnxruntime-int8 needs onnxscript \(the detector extra\): pip install"):
        runtime.check("onnxruntime-int8")
    runtime.check("torch")  # torch needs neither
