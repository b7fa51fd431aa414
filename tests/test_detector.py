"""The torch YOLO-v5 detector: official-checkpoint compatibility, training, mAP, attaching
detections to objects, the oracle, and sessions with a detector."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

torch = pytest.importorskip("torch")

from rosmeery_jax.apps.cli import main  # noqa: E402
from rosmeery_jax.core.errors import InputError  # noqa: E402
from rosmeery_jax.detector import checkpoint  # noqa: E402
from rosmeery_jax.detector.boxes import nms  # noqa: E402
from rosmeery_jax.detector.dataset import aim_shares, visible_boxes  # noqa: E402
from rosmeery_jax.detector.detections import DEFAULT_WEIGHTS, OracleDetector, associate  # noqa: E402
from rosmeery_jax.detector.mean_ap import average_precision, mean_ap  # noqa: E402
from rosmeery_jax.detector.yolo import YOLOv5  # noqa: E402

# The official yolov5n.pt is not shipped (no downloads at run time): point this variable at
# a copy to run the test (docs/architecture.md, "Tests").
OFFICIAL = Path(os.environ.get("ROSMEERY_YOLOV5N", "") or "/nonexistent/yolov5n.pt")


def _letterbox(img: np.ndarray, size: int = 640) -> torch.Tensor:
    h, w = img.shape[:2]
    s = size / max(h, w)
    x = torch.from_numpy(img).permute(2, 0, 1)[None].float() / 255
    nh, nw = round(h * s), round(w * s)
    x = torch.nn.functional.interpolate(x, size=(nh, nw), mode="bilinear", align_corners=False)
    return torch.nn.functional.pad(x, (0, (-nw) % 32, 0, (-nh) % 32), value=114 / 255)


@pytest.mark.skipif(not OFFICIAL.is_file(), reason="set ROSMEERY_YOLOV5N=/path/to/official/yolov5n.pt to run")
def test_official_checkpoint_loads_strictly_and_detects_photos():
    skimage_data = pytest.importorskip("skimage.data")
    model = checkpoint.load(OFFICIAL)  # strict=True inside; no pickled code runs
    assert (model.size, model.nc, model.names[0]) == ("n", 80, "person")
    assert sum(p.numel() for p in model.parameters()) == 1_872_157  # YOLOv5n's published count
    for image, wanted in ((skimage_data.astronaut(), "person"), (skimage_data.coffee(), "cup")):
        det = model.detect(_letterbox(image))[0]
        found = {model.names[int(c)] for c in det[:, 5]}
        assert wanted in found, found


def test_a_pickled_model_checkpoint_loads_without_running_its_classes(tmp_path):
    """The official format pickles whole model objects; in every clone (the official file is
    not shipped) a checkpoint pickled the same way, from classes the reader never imports,
    loads strictly and gives the same outputs."""
    torch.manual_seed(0)
    model = YOLOv5(3, "n", ["chair", "desk", "tv"]).eval()
    path = tmp_path / "pickled_model.pt"
    torch.save({"model": model, "ema": None, "epoch": 7}, path)  # a zip of pickled module objects
    loaded = checkpoint.load(path)
    assert (loaded.size, loaded.nc, loaded.names) == ("n", 3, ["chair", "desk", "tv"])
    x = torch.rand(1, 3, 64, 64)
    with torch.no_grad():
        torch.testing.assert_close(loaded(x), model(x))


def test_nano_and_small_have_the_official_layout():
    n, s = YOLOv5(80, "n"), YOLOv5(3, "s")
    keys = list(n.state_dict())
    assert keys[0] == "model.0.conv.weight" and "model.24.anchors" in keys and keys[-1] == "model.24.m.2.bias"
    assert n.state_dict()["model.24.m.0.weight"].shape == (255, 64, 1, 1)
    assert s.state_dict()["model.24.m.2.weight"].shape == (24, 512, 1, 1)
    raw = s(torch.zeros(2, 3, 128, 160))
    assert [tuple(r.shape) for r in raw] == [(2, 3, 16, 20, 8), (2, 3, 8, 10, 8), (2, 3, 4, 5, 8)]


def test_the_p2_graph_adds_a_stride_4_level_assigns_small_boxes_to_it_and_loads_back(tmp_path):
    from rosmeery_jax.detector.loss import YoloLoss

    model = YOLOv5(3, "n", ["a", "b", "c"], p2=True)
    keys = list(model.state_dict())
    assert "model.31.anchors" in keys and keys[-1] == "model.31.m.3.bias"  # official yolov5-p2 indices
    assert model.head.stride == (4, 8, 16, 32)
    assert model.head.anchors[0].mul(4).flatten().tolist() == [5, 6, 8, 15, 16, 11]  # pixels
    raw = model(torch.zeros(2, 3, 128, 160))
    assert [tuple(r.shape) for r in raw] == [(2, 3, 32, 40, 8), (2, 3, 16, 20, 8), (2, 3, 8, 10, 8),
                                           (2, 3, 4, 5, 8)]
    # A 6 x 8 px box centred at (82, 66) px: at stride 4 its centre is (20.5, 16.5), no
    # neighbour is nearer than half a cell, so all three P2 anchors (within 4x its shape)
    # take it in cell (16, 20) alone.
    target = torch.tensor([[0, 1, 82 / 160, 66 / 128, 6 / 160, 8 / 128]])
    b, a, gj, gi, _, _, c = next(YoloLoss(model, 160)._assign(raw, target))
    assert sorted(a.tolist()) == [0, 1, 2] and set(zip(gj.tolist(), gi.tolist())) == {(16, 20)}
    assert c.tolist() == [1, 1, 1]
    checkpoint.save(model, tmp_path / "p2.pt", (128, 160))
    back = checkpoint.load(tmp_path / "p2.pt")
    x = torch.rand(1, 3, 64, 96)
    assert back.p2 and not checkpoint.load(DEFAULT_WEIGHTS).p2
    torch.testing.assert_close(back.decoded(x), model.eval().decoded(x), atol=0.02, rtol=0.01)  # fp16 on disk


def test_nms_keeps_the_best_of_overlapping_boxes_per_class():
    # decoded rows: cx, cy, w, h, objectness, class probabilities (2 classes)
    pred = np.array([[[50, 50, 20, 20, 0.9, 0.9, 0.1],
                          [52, 50, 20, 20, 0.8, 0.9, 0.1],   # overlaps the first, same class: dropped
                          [52, 50, 20, 20, 0.8, 0.1, 0.9],   # same place, other class: kept
                          [150, 50, 20, 20, 0.1, 0.9, 0.1]]], np.float32)  # below the threshold
    out = nms(pred, conf=0.25, iou=0.45)[0]
    assert out.shape == (2, 6)
    np.testing.assert_allclose(out[:, 4], [0.81, 0.72], rtol=1e-6)
    assert out[:, 5].tolist() == [0.0, 1.0]


def test_average_precision_by_hand():
    # 2 ground-truth boxes; detections by confidence: TP, FP, TP ->
    # precision 1, 1/2, 2/3 at recall 1/2, 1/2, 1: best precision at recall >= r is 1 for the
    # 51 points r <= 0.5 and 2/3 for the 50 points above.
    ap = average_precision(np.array([True, False, True]), np.array([0.9, 0.8, 0.7]), 2)
    assert ap == pytest.approx((51 + 50 * 2 / 3) / 101, abs=1e-9)
    gt = [np.array([[0, 0, 0, 10, 10], [1, 20, 20, 30, 30]], np.float32)]
    perfect = [np.array([[0, 0, 10, 10, 0.9, 0], [20, 20, 30, 30, 0.8, 1]], np.float32)]
    assert mean_ap(perfect, gt, 2)["map50"] == pytest.approx(1.0)
    wrong_class = [np.array([[0, 0, 10, 10, 0.9, 1], [20, 20, 30, 30, 0.8, 1]], np.float32)]
    r = mean_ap(wrong_class, gt, 2)
    # class 1: a false positive (0.9) ranked above its true positive (0.8): precision 1/2 at recall 1
    assert r["ap"][0] == 0.0 and r["ap"][1] == pytest.approx(0.5)


def test_a_detection_attaches_to_the_object_covering_most_of_its_box():
    seg = np.full((20, 20), -1, np.int32)
    seg[2:10, 2:10] = 3   # 64 px
    seg[8:18, 8:18] = 5   # 100 px, overlapping
    boxes = np.array([[2, 2, 10, 10], [6, 6, 18, 18], [12, 0, 20, 6], [0, 0, 20, 20]], np.float32)
    assert associate(boxes, seg).tolist() == [3, 5, -1, 5]


def _boxes_by_mask(labels: np.ndarray, min_pixels: int) -> np.ndarray:
    """visible_boxes by definition: one mask per object."""
    rows = []
    for o in np.unique(labels[labels >= 0]):
        ys, xs = np.nonzero(labels == o)
        if len(xs) >= min_pixels:
            rows.append((o, xs.min(), ys.min(), xs.max() + 1, ys.max() + 1, len(xs)))
    return np.array(rows, np.int64).reshape(-1, 6)


def test_a_balanced_dataset_aims_at_every_category_equally_often():
    """Three chairs and one table: each chair gets a sixth of the aims, the table half."""
    np.testing.assert_allclose(aim_shares(np.array([4, 4, 4, 9])), [1 / 6, 1 / 6, 1 / 6, 1 / 2])
    np.testing.assert_allclose(aim_shares(np.array([2, 7])), [0.5, 0.5])


def test_dataset_frames_are_the_unpadded_scenes_bitwise_and_share_one_compile():
    """render_world pads each scene to a bucket of boxes so that worlds share a compile; the
    padding must change no pixel, colour scales included, and two worlds in one bucket must
    not compile again."""
    import jax

    from rosmeery_jax.detector import dataset
    from rosmeery_jax.raycast.kernel import ray_scene
    from rosmeery_jax.raycast.sensors import CameraConfig, rgb
    from rosmeery_jax.world import load_world

    worlds = [load_world(n) for n in ("kitchen", "large_office")]  # 205 and 226 boxes: one bucket
    poses = np.array([[0.5, 0.5, 0.3], [2.0, -1.0, 2.5], [-1.0, 2.0, -1.2]], np.float32)
    dataset.renderer().clear_cache()
    for w in worlds:
        rs = ray_scene(w.scene)
        scale = np.random.default_rng(0).uniform(0.6, 1.4, (len(poses), rs.num_boxes + 1, 3)).astype(np.float32)
        img, lab = dataset.render_world(w, poses, scale, batch=4)

        def plain(p, s, rs=rs):
            g = rs.num_boxes
            return rgb(rs._replace(rgb=jax.numpy.clip(rs.rgb * s[:g], 0, 1),
                                   floor_rgb=jax.numpy.clip(rs.floor_rgb * s[g], 0, 1)), CameraConfig(), p)
        ref_img, ref_lab = jax.jit(jax.vmap(plain))(poses, scale)
        assert np.array_equal(img, np.asarray(ref_img)) and np.array_equal(lab, np.asarray(ref_lab))
        assert (lab >= 0).any()  # the poses see objects: the comparison is not of empty frames
    assert dataset.renderer()._cache_size() == 1


def test_near_viewpoints_stand_close_to_their_object_where_the_robot_can_stand():
    from rosmeery_jax.detector import dataset
    from rosmeery_jax.world import load_world

    w = load_world("large_office")
    fs, centres = w.free_space, w.truth.bbox_center[:, :2]
    ii, jj = np.nonzero(fs.reachable)
    cell_xy = np.stack([fs.origin[0] + (jj + 0.5) * fs.resolution, fs.origin[1] + (ii + 0.5) * fs.resolution], -1)
    gap = np.linalg.norm(cell_xy[None] - centres[:, None], axis=-1)
    room = ((gap >= dataset.NEAR[0]) & (gap <= dataset.NEAR[1])).any(1)  # objects with a place to stand near
    assert room.sum() >= 2 and not room.all()
    pick = np.repeat(centres[[*np.flatnonzero(room)[:2], np.flatnonzero(~room)[0]]], 40, 0)
    xy = np.zeros((120, 2))
    which = np.arange(120) % 4 != 0  # a quarter stay where they were
    moved = dataset._near(xy, pick, which, fs, ii, jj, np.random.default_rng(0))
    d = np.linalg.norm(moved - pick, axis=-1)
    slack = fs.resolution * np.sqrt(2) / 2  # a cell's centre within NEAR, the point anywhere in the cell
    can = which & (np.arange(120) < 80)  # the third object has no place near: its viewpoints stay
    assert (d[can] >= dataset.NEAR[0] - slack).all() and (d[can] <= dataset.NEAR[1] + slack).all()
    assert (moved[~can] == 0).all()
    cells = np.floor((moved[can] - fs.origin) / fs.resolution).astype(int)
    assert fs.reachable[cells[:, 1], cells[:, 0]].all()
    # through viewpoints: every pose reachable, and the aimed ones turned towards an object
    near = dataset.viewpoints(w, dataset.DatasetConfig(per_world=200, aim=1.0, near=1.0), np.random.default_rng(3))
    cells = np.floor((near[:, :2] - fs.origin) / fs.resolution).astype(int)
    assert fs.reachable[cells[:, 1], cells[:, 0]].all()
    ahead = centres[None] - near[:, None, :2]
    off = np.abs(np.angle(np.exp(1j * (np.arctan2(ahead[..., 1], ahead[..., 0]) - near[:, 2:3])))).min(1)
    assert np.median(off) < 0.35


def test_clear_lines_and_footprint_corners_by_hand():
    from rosmeery_jax.detector import dataset
    from rosmeery_jax.world.freespace import FreeSpace

    occ = np.zeros((10, 10), bool)
    occ[:, 5] = True  # a wall at x in [0.5, 0.6) m, 10 cm cells from the origin
    occ[9, 5] = False  # with a gap at the top row
    fs = FreeSpace(np.zeros(2), 0.1, occ, ~occ, ~occ, np.ones((10, 10), np.float32))
    start = np.array([[0.15, 0.15], [0.15, 0.15], [0.15, 0.95], [0.15, 0.15]])
    end = np.array([[0.45, 0.85], [0.85, 0.15], [0.85, 0.95], [0.55, 0.15]])
    # along the wall's side / through the wall / through the gap / ending in the wall's cell,
    # 0.1 m short of its end
    assert dataset.clear_line(fs, start, end, 0.0).tolist() == [True, False, True, False]
    assert dataset.clear_line(fs, start, end, 0.1).tolist() == [True, False, True, True]

    class Truth:  # one 2 x 1 m object at (3, 4) turned a quarter turn: 1 m along x, 2 m along y
        bbox_center, bbox_size, bbox_yaw = np.array([[3.0, 4.0, 0.5]]), np.array([[2.0, 1.0, 1.0]]), np.array([np.pi / 2])

    corners = dataset.footprint_corners(Truth, np.array([0]), inset=1.0)
    assert corners.shape == (1, 4, 2)
    np.testing.assert_allclose(sorted(map(tuple, corners[0].round(6))), [(2.5, 3.0), (2.5, 5.0), (3.5, 3.0), (3.5, 5.0)])


def test_far_viewpoints_stand_far_from_their_object_and_see_a_corner_of_it():
    from rosmeery_jax.detector import dataset
    from rosmeery_jax.world import load_world
    from rosmeery_jax.world.taxonomy import load_taxonomy

    w = load_world("kitchen")
    fs, centres = w.free_space, w.truth.bbox_center[:, :2]
    toilet = np.flatnonzero(np.asarray(w.truth.category_index) == load_taxonomy().names.index("toilet"))
    pick = np.repeat(centres[toilet], 40, 0)  # the Kitchen's toilet, seen through a doorway from afar
    which = np.arange(40) % 4 != 0  # a quarter stay where they were
    ii, jj = np.nonzero(fs.reachable)
    corners = dataset.footprint_corners(w.truth, np.repeat(toilet, 40))
    moved = dataset._far(np.zeros((40, 2)), pick, which, corners, fs, ii, jj, np.random.default_rng(0))
    assert (moved[~which] == 0).all()
    d = np.linalg.norm(moved[which] - pick[which], axis=-1)
    slack = fs.resolution * np.sqrt(2) / 2  # a cell's centre within FAR, the point anywhere in the cell
    assert (d >= dataset.FAR[0] - slack).all() and (d <= dataset.FAR[1] + slack).all()
    cells = np.floor((moved[which] - fs.origin) / fs.resolution).astype(int)
    assert fs.reachable[cells[:, 1], cells[:, 0]].all()
    centre = fs.origin + (cells + 0.5) * fs.resolution  # the lines are drawn from cell centres
    seen = np.zeros(len(centre), bool)
    for corner in corners[which].transpose(1, 0, 2):
        seen |= dataset.clear_line(fs, centre, corner, dataset.FAR_STOP)
    assert seen.all()
    # a line to the toilet's centre is blocked from all of them: it is seen only in part
    assert not dataset.clear_line(fs, centre, pick[which], 0.4).any()
    # through viewpoints: every pose reachable, most turned towards an object 4-10 m away
    poses = dataset.viewpoints(w, dataset.DatasetConfig(per_world=200, aim=1.0, far=1.0), np.random.default_rng(5))
    cells = np.floor((poses[:, :2] - fs.origin) / fs.resolution).astype(int)
    assert fs.reachable[cells[:, 1], cells[:, 0]].all()
    ahead = centres[None] - poses[:, None, :2]
    off = np.abs(np.angle(np.exp(1j * (np.arctan2(ahead[..., 1], ahead[..., 0]) - poses[:, 2:3]))))
    dist = np.linalg.norm(ahead, axis=-1)
    far = (dist >= dataset.FAR[0] - slack) & (dist <= dataset.FAR[1] + slack)
    assert (far & (off < 0.35)).any(1).mean() > 0.6


def test_more_weights_the_balanced_aim_and_bad_weights_are_one_error(tmp_path, capsys):
    np.testing.assert_allclose(aim_shares(np.array([4, 4, 4, 9]), {9: 2.0}), [1 / 9, 1 / 9, 1 / 9, 2 / 3])
    np.testing.assert_allclose(aim_shares(np.array([4, 4, 4, 9]), {5: 3.0}), aim_shares(np.array([4, 4, 4, 9])))
    base = ["detector", "dataset", "--worlds", "kitchen", "--per-world", "4", "--out", str(tmp_path / "d")]
    for more, extra, words in [("sofa_bed=2", ["--balance"], "sofa_bed=2.0: name a category"),
                               ("toilet=0", ["--balance"], "toilet=0.0: name a category"),
                               ("toilet", ["--balance"], "'toilet' is not CATEGORY=FACTOR"),
                               ("toilet=2", [], "weights the balanced aim: give --balance too")]:
        assert main([*base, "--more", more, *extra]) == 2
        assert f"command line: --more: {words}" in capsys.readouterr().err
    assert main([*base, "--far", "1.5"]) == 2
    assert "command line: --far: 1.5 must be a share between 0 and 1" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


def test_visible_boxes_by_hand():
    seg = np.full((6, 8), -1, np.int32)
    seg[1:3, 2:5] = 7  # 6 px
    seg[4, 0] = seg[5, 7] = 2  # 2 px in opposite corners: the box spans the bottom two rows
    assert visible_boxes(seg, 1).tolist() == [[2, 0, 4, 8, 6, 2], [7, 2, 1, 5, 3, 6]]
    assert visible_boxes(seg, 3).tolist() == [[7, 2, 1, 5, 3, 6]]
    assert visible_boxes(np.full((4, 4), -3), 1).shape == (0, 6)


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 12), st.integers(1, 12), st.integers(1, 6), st.integers(0, 2**32 - 1))
def test_visible_boxes_match_one_mask_per_object(h, w, min_pixels, seed):
    seg = np.random.default_rng(seed).integers(-3, 5, (h, w)).astype(np.int32)
    got = visible_boxes(seg, min_pixels)
    assert got.dtype == np.int64 and np.array_equal(got, _boxes_by_mask(seg, min_pixels))


def test_oracle_is_deterministic_and_within_the_confidence_model():
    from rosmeery_jax.world.taxonomy import load_taxonomy

    tax = load_taxonomy()
    seg = np.full((3, 64, 80), -1, np.int32)
    seg[:, 10:40, 10:50] = 0   # 1200 px: a large object, s = 1
    seg[:, 50:56, 60:66] = 1   # 36 px: below min_pixels, never detected
    oracle = OracleDetector(np.array([tax.index("chair"), tax.index("desk")]), tax, conf=0.2)
    ids = np.array([[0, 0], [0, 1], [1, 0]])
    a, b = oracle(None, seg, ids), oracle(None, seg, ids)
    for (o1, l1, c1, b1), (o2, l2, c2, _) in zip(a, b):
        assert o1.tolist() == o2.tolist() and np.array_equal(c1, c2)
        assert set(o1.tolist()) <= {0}
        assert all(box.tolist() == [10, 10, 50, 40] for box in b1)  # x1, y1, x2, y2 of the object's pixels
        assert np.all((c1 >= 0.2) & (c1 <= 0.99))
        assert all(lab == tax.index("chair") for lab in l1)  # s = 1: never a wrong label


def test_corrupt_or_mismatched_weights_give_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint at all")
    with pytest.raises(InputError, match="bad.pt"):
        checkpoint.load(bad)
    other = YOLOv5(3, "n", ["a", "b", "c"])
    mismatched = tmp_path / "mismatched.pt"
    checkpoint.save(other, mismatched, (128, 160))
    sd = torch.load(mismatched, weights_only=True)
    sd["state_dict"].pop("model.24.m.0.bias")
    torch.save(sd, mismatched)
    with pytest.raises(InputError, match="state_dict"):
        checkpoint.load(mismatched)
    assert main(["detector", "eval", "--weights", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad.pt" in err


def test_saved_weights_load_back_the_same_and_name_no_temporary_file(tmp_path):
    import zipfile

    model = YOLOv5(3, "n", ["a", "b", "c"])
    out = tmp_path / "mine.pt"
    checkpoint.save(model, out, (128, 160), {"note": "x"})
    assert [p.name for p in tmp_path.iterdir()] == ["mine.pt"]  # the temporary file is gone
    assert {n.split("/")[0] for n in zipfile.ZipFile(out).namelist()} == {"archive"}
    back = checkpoint.load(out)
    for k, v in model.state_dict().items():
        want = v.half().float() if v.is_floating_point() else v
        assert torch.equal(back.state_dict()[k], want), k
    assert torch.load(out, weights_only=True)["meta"] == {"note": "x"}


_FIELD_VALUES = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True),
                          st.text(max_size=8), st.lists(st.integers(-5, 10**5), max_size=3),
                          st.dictionaries(st.text(max_size=4), st.integers(), max_size=2))


@settings(max_examples=40, deadline=None)
@given(field=st.sampled_from(["names", "size", "imgsz", "meta", "meta.int8_percentile"]), value=_FIELD_VALUES)
def test_a_weights_file_with_any_field_wrong_loads_or_names_that_field(tmp_path_factory, field, value):
    """Whatever one field of our format holds, the file loads into a model the detector can
    use (an input size of two positive whole numbers or none, a percentage or none), or one
    error names the file and that field."""
    path = tmp_path_factory.mktemp("w") / "w.pt"
    raw = {"format": checkpoint.FORMAT, "size": "n", "names": ["a", "b", "c"], "imgsz": [128, 160],
           "meta": {}, "state_dict": YOLOv5(3, "n", ["a", "b", "c"]).state_dict()}
    if field == "meta.int8_percentile":
        raw["meta"] = {"int8_percentile": value}
    else:
        raw[field] = value
    torch.save(raw, path)
    try:
        model = checkpoint.load(path)
    except InputError as err:
        assert str(err).startswith(f"{path}: ") and field.split(".")[0] in str(err)
        return
    assert model.imgsz is None or (len(model.imgsz) == 2 and all(type(v) is int and v > 0 for v in model.imgsz))
    assert model.int8_percentile is None or 0 < model.int8_percentile <= 100
    assert all(isinstance(n, str) for n in model.names)


def test_a_damaged_weights_archive_is_refused_before_any_unpickler_reads_it(tmp_path, monkeypatch):
    """Three bytes before the first entry shifted every read of torch's zip reader, and its
    unpickler then asked for about 20 GB; a flipped byte inside an entry fails its CRC.
    Both are one error naming the file, and neither reaches torch.load."""
    import zipfile

    good = DEFAULT_WEIGHTS.read_bytes()
    with zipfile.ZipFile(DEFAULT_WEIGHTS) as zf:
        entry = zf.getinfo(next(n for n in zf.namelist() if n.endswith("data.pkl")))
    flip = entry.header_offset + 30 + len(entry.filename) + len(entry.extra) + 100  # in data.pkl's bytes
    shifted, flipped = tmp_path / "shifted.pt", tmp_path / "flipped.pt"
    shifted.write_bytes(b"abc" + good)
    flipped.write_bytes(good[:flip] + bytes([good[flip] ^ 0xFF]) + good[flip + 1:])
    monkeypatch.setattr(torch, "load", lambda *a, **k: pytest.fail("torch.load reached"))
    with pytest.raises(InputError, match=r"shifted\.pt: file: damaged zip archive \(data before its first entry\)"):
        checkpoint.load(shifted)
    with pytest.raises(InputError, match=r"flipped\.pt: .*data\.pkl: damaged entry \(CRC mismatch\)"):
        checkpoint.load(flipped)


def test_training_from_scratch_on_a_tiny_generated_dataset_reduces_the_loss(tmp_path):
    data, out = tmp_path / "data", tmp_path / "w.pt"
    assert main(["detector", "dataset", "--worlds", "small_office", "--per-world", "48", "--out", str(data),
                 "--quiet"]) == 0
    assert sorted(p.name for p in data.iterdir()) == ["data.json", "images", "labels"]
    labels = list((data / "labels" / "train").glob("*.txt"))
    rows = np.concatenate([np.loadtxt(p, ndmin=2).reshape(-1, 5) for p in labels if p.stat().st_size])
    assert np.all((rows[:, 1:] >= 0) & (rows[:, 1:] <= 1)) and len(rows) > 20
    assert main(["detector", "train", "--data", str(data), "--out", str(out), "--epochs", "4", "--batch", "8",
                 "--quiet"]) == 0
    log = pd.read_csv(tmp_path / "w.log.csv")
    total = log[["box", "obj", "cls"]].sum(axis=1)
    assert len(log) == 4 and total.iloc[-1] < total.iloc[0]
    model = checkpoint.load(out)  # fp16 on disk, float32 when loaded
    assert model.nc == 27 and next(model.parameters()).dtype == torch.float32


def test_a_mosaic_puts_each_frame_at_half_size_in_its_quadrant_with_its_boxes():
    from rosmeery_jax.detector.train import augment, mosaic

    tiles = torch.stack([torch.full((3, 8, 12), float(q)) for q in range(4)])  # frame q is all q
    rows = [np.array([[q, 0.5, 0.5, 0.5, 0.5]], np.float32) for q in range(4)]  # a 6 x 4 box in the middle
    img, out = mosaic(tiles, rows)
    assert img.shape == (3, 8, 12)
    for q in range(4):  # quadrant q (6 x 4 pixels) holds frame q, and its box: 3 x 2 pixels at its middle
        y, x = q // 2 * 4, q % 2 * 6
        assert torch.all(img[:, y:y + 4, x:x + 6] == q)
        np.testing.assert_allclose(out[q], [q, (x + 3) / 12, (y + 2) / 8, 3 / 12, 2 / 8], atol=1e-6)
    tiny = [np.array([[0, 0.5, 0.5, 3 / 12, 0.5]], np.float32)] + rows[1:]  # 3 px wide: 1.5 at half size
    assert list(mosaic(tiles, tiny)[1][:, 0]) == [1, 2, 3]
    x = torch.rand(4, 3, 8, 12)
    a, b = augment(x, rows, np.random.default_rng(5)), augment(x, rows, np.random.default_rng(5), 0.0)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])  # mosaic 0: the augmentation as without it
    big = [np.array([[q, 0.5, 0.5, 0.3, 0.3]], np.float32) for q in range(4)]
    _, t = augment(torch.rand(4, 3, 48, 64), big, np.random.default_rng(5), 1.0)
    per_image = np.bincount(t[:, 0].int().numpy(), minlength=4)
    assert per_image.min() >= 1 and per_image.max() == 4  # one box a frame: four only in a mosaic (a zoom
    # may cut up to three)


def test_the_jax_core_never_imports_torch():
    code = ("import sys, rosmeery_jax, rosmeery_jax.env.environment, rosmeery_jax.session.runner, rosmeery_jax.metrics.indices, "
            "rosmeery_jax.detector.dataset; assert 'torch' not in sys.modules, 'torch imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_importing_the_command_line_starts_no_jax_backend():
    """--devices makes host devices from the cores, which JAX allows only before it starts:
    no import of the command line (session config, detector, dataset) may start it."""
    code = ("import rosmeery_jax.apps.cli, rosmeery_jax.session.config, rosmeery_jax.detector.dataset; "
            "from rosmeery_jax.core import xla; assert not xla.started(), 'JAX started on import'")
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.skipif(not DEFAULT_WEIGHTS.is_file(), reason="shipped weights missing")
def test_shipped_weights_are_small_fp16_and_load():
    assert DEFAULT_WEIGHTS.stat().st_size <= 8 * 2 ** 20
    raw = torch.load(DEFAULT_WEIGHTS, weights_only=True)
    assert raw["state_dict"]["model.0.conv.weight"].dtype == torch.float16
    assert checkpoint.load(DEFAULT_WEIGHTS).nc == 27


def test_the_default_detector_was_trained_on_generated_worlds_only():
    """The default weights carry their dataset's configuration; the manifest of their recipe
    lists the same worlds, and every one is a procedural world (no paper world, no file)."""
    import json

    from rosmeery_jax.detector.detections import WEIGHTS
    from rosmeery_jax.world.procedural import parse_name

    assert DEFAULT_WEIGHTS == WEIGHTS["procedural"] and DEFAULT_WEIGHTS.is_file()
    meta = torch.load(DEFAULT_WEIGHTS, weights_only=True)["meta"]
    recipe = Path(__file__).resolve().parents[1] / "detector"
    manifest = json.loads((recipe / "dataset.json").read_text())["dataset"]
    assert meta["dataset"] == manifest and len(manifest["worlds"]) == 240
    kinds = {parse_name(w).kind for w in manifest["worlds"]}  # raises on any other name
    assert kinds == {"apartment", "office", "kitchen", "lab"}
    paper = torch.load(WEIGHTS["paper_worlds"], weights_only=True)["meta"]["dataset"]["worlds"]
    assert sorted(paper) == ["kitchen", "laboratory", "large_office", "small_office"]  # the named option


def test_the_twice_the_size_weights_are_the_default_fine_tuned_on_generated_worlds_only():
    """``procedural_2x``: the default weights (by content) fine-tuned at 320 x 256 on a dataset
    whose manifest lists the same worlds as the weights, every one a procedural world."""
    import hashlib
    import json

    from rosmeery_jax.detector.detections import WEIGHTS
    from rosmeery_jax.world.procedural import parse_name

    raw = torch.load(WEIGHTS["procedural_2x"], weights_only=True)
    assert raw["imgsz"] == [256, 320]  # twice the session's 128 x 160 frames
    settings = raw["meta"]["fine_tune"]
    assert settings["base_sha256"] == hashlib.sha256(DEFAULT_WEIGHTS.read_bytes()).hexdigest()
    assert settings["scale"] == 2 and raw["meta"]["int8_percentile"] == 99.95  # its int8 calibration (model card)
    recipe = Path(__file__).resolve().parents[1] / "detector"
    manifest = json.loads((recipe / "dataset_2x.json").read_text())["dataset"]
    assert raw["meta"]["dataset"] == manifest and len(manifest["worlds"]) == 240
    assert {parse_name(w).kind for w in manifest["worlds"]} == {"apartment", "office", "kitchen", "lab"}


def test_weights_are_named_or_a_path_and_a_bad_name_gives_one_line(tmp_path, capsys):
    from rosmeery_jax.detector.detections import WEIGHTS, weights_file

    assert weights_file(None) == weights_file("") == DEFAULT_WEIGHTS
    assert weights_file("paper_worlds") == WEIGHTS["paper_worlds"] != DEFAULT_WEIGHTS
    assert weights_file(tmp_path / "mine.pt") == tmp_path / "mine.pt"
    code = main(["run", "--worlds", "small_office", "--policies", "random", "--seeds", "1", "--duration", "5",
                 "--weights", "paper_world", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "weights" in err and "paper_worlds" in err and not (tmp_path / "out").exists()


@pytest.mark.parametrize("detector", ["yolo", "oracle"])
def test_session_with_a_detector_scores_confidences_and_labels(tmp_path, detector, capsys):
    out = tmp_path / detector
    assert main(["run", "--worlds", "small_office", "--policies", "random", "--seeds", "2", "--duration", "20",
                 "--detector", detector, "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "detector: 40 frames" in printed and "mappers (fed and scored)" not in printed  # no mapper ran
    df = pd.read_csv(out / "metrics.csv")
    wide = df.pivot_table(index=["seed", "time_s"], columns="metric", values="value")
    assert (wide.cori <= wide.ori + 1e-9).all()
    assert wide.cori.iloc[-1] > 0
    objects = pd.read_csv(out / "objects.csv")
    detected = objects[objects.label.notna()]
    assert len(detected) > 0 and (detected.confidence > 0).all()
    final = wide.groupby("seed").last()
    for seed, g in objects.groupby("seed"):
        has_wrong = bool(((g.label != g.category) & g.label.notna()).any())
        # OPI counts any declared predicate; OPI-strict only true ones, so a wrong label shows.
        assert (final.loc[seed, "opi_strict"] < final.loc[seed, "opi"] - 1e-9) == has_wrong


@pytest.mark.skipif(not DEFAULT_WEIGHTS.is_file(), reason="shipped weights missing")
def test_yolo_detections_do_not_depend_on_batch_mates_or_place_in_the_batch():
    """The session batches frames of several worlds and envs together: a frame's detections
    must be the same whatever frames share its batch and wherever it sits in it."""
    import jax
    import jax.numpy as jnp

    from rosmeery_jax.apps.bench import random_targets
    from rosmeery_jax.detector.detections import make_detector
    from rosmeery_jax.env import make
    from rosmeery_jax.raycast.sensors import rgbd

    env = make("small_office")
    poses = jnp.asarray(random_targets(env.world, 70, 4))
    img, _, seg = (np.asarray(a) for a in jax.jit(jax.vmap(lambda p: rgbd(env.rays, env.config.camera, p)))(poses))
    det = make_detector("yolo", env.world, 0.25)
    alone = det.forward(img)
    assert sum(len(d) for d in alone) > 20  # not vacuous: the frames hold detections
    order = np.random.default_rng(0).permutation(len(img))
    mixed = det.forward(img[order])  # other batch-mates, other places, a second partial batch
    assert all(np.array_equal(mixed[i], alone[j]) for i, j in enumerate(order))
    assert all(np.array_equal(a, b) for a, b in zip(det.forward(img[:5]), alone[:5]))
    assert all(np.array_equal(a[0], b[0]) for a, b in zip(det(img, seg), det.finish(alone, seg)))


@pytest.mark.skipif(not DEFAULT_WEIGHTS.is_file(), reason="shipped weights missing")
def test_yolo_sees_each_distinct_image_once_and_remembers_the_latest():
    """A robot standing still sends the same frame again: raw() gives it the network's
    detections on that image (the test above: they depend on nothing else) without a pass."""
    import jax
    import jax.numpy as jnp

    from rosmeery_jax.apps.bench import random_targets
    from rosmeery_jax.detector.detections import make_detector
    from rosmeery_jax.env import make
    from rosmeery_jax.raycast.sensors import rgb

    env = make("small_office")
    poses = jnp.asarray(random_targets(env.world, 26, 4))
    img = np.asarray(jax.jit(jax.vmap(lambda p: rgb(env.rays, env.config.camera, p)))(poses)[0])
    forward = make_detector("yolo", env.world, 0.25).forward
    alone = forward(img)
    det, passes = make_detector("yolo", env.world, 0.25), []
    det.forward = lambda images: passes.append(len(images)) or forward(images)
    det.raw(img[:3])
    got = det.raw(img[[0, 1, 2, 0, 1, 2, 10, 11]])  # 3 seen before, 3 repeats, 2 new
    assert passes == [3, 2] and all(np.array_equal(a, alone[i]) for a, i in zip(got, [0, 1, 2, 0, 1, 2, 10, 11]))
    assert len(det.raw(img[[11, 10, 0]])) == 3 and passes == [3, 2]  # all known: no network pass
    det.memory = 4
    det.raw(img[20:26])  # 6 new images; only the 4 most recent are kept
    assert passes == [3, 2, 6] and len(det._known) == 4
    det.raw(img[20:21])  # forgotten: the network sees it again
    assert passes == [3, 2, 6, 1]


def test_detect_runs_one_pass_per_shared_network_and_returns_each_row_its_frames():
    from types import SimpleNamespace

    from rosmeery_jax.session import program, worker

    class Net:
        """Raw detections encode the frame (its first pixel); finish tags them with the world."""

        calls = 0

        def __init__(self, world, network):
            self.world, self.network = world, network

        def raw(self, images):
            Net.calls += 1
            return [np.array([[0, 0, 1, 1, 0.9, im[0, 0, 0]]], np.float32) for im in images]

        def finish(self, raw, seg):
            return [(np.array([self.world], np.int32), d[:, 5].astype(np.int32), d[:, 4], d[:, :4]) for d in raw]

        def __call__(self, images, seg, ids):
            return self.finish(self.raw(images), seg)

    b, f = 6, 3
    group = SimpleNamespace(real=np.array([1, 1, 0, 1, 1, 1], bool), world=np.array([0, 0, 0, 1, 1, 2]),
                            seed=np.arange(b))
    rgb = np.zeros((b, f, 4, 4, 3), np.uint8)
    rgb[..., 0, 0, 0] = (np.arange(b)[:, None] * 10 + np.arange(f)).astype(np.uint8)
    dets = {0: Net(0, "yolo"), 1: Net(1, "yolo"), 2: Net(2, None)}
    obj, label, conf, box = worker._detect(group, dets, program.Frames(rgb, np.zeros((b, f, 4, 4), np.int16), None), 0)
    assert Net.calls == 2  # worlds 0 and 1 share one pass; world 2 has its own
    for r in range(b):
        if group.real[r]:
            assert (obj[r, :, 0] == group.world[r]).all() and (label[r, :, 0] == r * 10 + np.arange(f)).all()
        else:
            assert (obj[r] == -1).all()  # a padding env gets no detections


@pytest.mark.parametrize("case, where", [
    ("1.7 0.5 0.5 0.2 0.2", "a.txt: row 1"), ("27 0.5 0.5 0.2 0.2", "a.txt: row 1"),  # counted as class 1 / a crash
    ("-1 0.5 0.5 0.2 0.2", "a.txt: row 1"), ("0 nan 0.5 0.2 0.2", "a.txt: row 1"),  # -1 was the last class
    ("0 0.5 0.5 0.2 0.2\n0 5 5 0.2 0.2", "a.txt: row 2"), ("0 0.5 0.5 0 0.2", "a.txt: row 1"),
    ("size", "b.png: image: 160x96 pixels, not 160x128"), ("json", "data.json: file: not valid JSON"),
])
def test_a_bad_dataset_is_one_error_naming_file_and_row(tmp_path, case, where):
    import cv2

    from rosmeery_jax.detector import dataset

    (tmp_path / "images" / "val").mkdir(parents=True)
    (tmp_path / "labels" / "val").mkdir(parents=True)
    (tmp_path / "data.json").write_text("{bad" if case == "json" else "{}")
    for name, h in (("a", 128), ("b", 96 if case == "size" else 128)):
        cv2.imwrite(str(tmp_path / "images" / "val" / f"{name}.png"), np.full((h, 160, 3), 99, np.uint8))
        rows = case if name == "a" and case not in ("size", "json") else "3 0.5 0.5 0.2 0.2"
        (tmp_path / "labels" / "val" / f"{name}.txt").write_text(rows + "\n")
    with pytest.raises(InputError) as err:
        dataset.read(tmp_path, "val")
    assert where in str(err.value) and "\n" not in str(err.value)
    (tmp_path / "data.json").write_text("{}")  # the same files, made good, read
    (tmp_path / "labels" / "val" / "a.txt").write_text("3 0.5 0.5 0.2 0.2\n26 1 0 0.1 1\n")
    if case != "size":
        images, rows, _ = dataset.read(tmp_path, "val")
        assert images.shape == (2, 128, 160, 3)
        np.testing.assert_allclose(rows[0], [[3, 0.5, 0.5, 0.2, 0.2], [26, 1, 0, 0.1, 1]], rtol=1e-6)


def _fine_tune_module():
    """detector/fine_tune.py (a script, not a package module)."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "detector" / "fine_tune.py"
    spec = importlib.util.spec_from_file_location("fine_tune", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_an_occluder_cuts_the_boxes_it_spans_to_what_stays_in_sight():
    """Hand-computed: a band across a box's whole width cuts its top or bottom away; one
    across its height, a side; one inside it or over a corner leaves it; hidden, it goes."""
    cut = _fine_tune_module().cut
    box = np.array([10.0, 20.0, 30.0, 60.0])
    assert cut(box, np.array([0, 0, 40, 35])).tolist() == [10, 35, 30, 60]  # top hidden
    assert cut(box, np.array([5, 50, 35, 70])).tolist() == [10, 20, 30, 50]  # bottom hidden
    assert cut(box, np.array([0, 10, 18, 70])).tolist() == [18, 20, 30, 60]  # left side hidden
    assert cut(box, np.array([5, 30, 35, 40])).tolist() == box.tolist()  # a band inside: extent kept
    assert cut(box, np.array([0, 0, 15, 25])).tolist() == box.tolist()  # a corner: kept
    assert cut(box, np.array([50, 0, 60, 80])).tolist() == box.tolist()  # beside it
    assert cut(box, np.array([0, 0, 40, 80])) is None  # whole
    assert cut(box, np.array([0, 0, 40, 58])) is None  # 2 px left in sight
    assert cut(box, np.array([12, 22, 40, 80])) is None  # 86 % covered, over a corner
