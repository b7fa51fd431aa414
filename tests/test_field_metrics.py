"""The field's map metrics (rosmeery_jax.metrics.field) on small built maps with answers
computed by hand (docs/metrics.md), their invariances, and their place in `evaluate`.

The world of the hand-computed cases: object A (category 0) and object B (category 1),
each a 3 x 3 x 3 lattice of samples 0.3 m apart (27 samples) filling its box exactly:
A's box centred at (0, 0, 0.5), B's at (3, 0, 0.5), both 0.6 m a side, no yaw."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rosmeery_jax.metrics import field
from rosmeery_jax.metrics.field_kernels import box_iou, class_ap

LATTICE = np.stack(np.meshgrid([-0.3, 0.0, 0.3], [-0.3, 0.0, 0.3], [0.2, 0.5, 0.8], indexing="ij"), -1).reshape(-1, 3)
A, B = LATTICE, LATTICE + [3.0, 0.0, 0.0]
TRUTH = field.FieldTruth.build(np.r_[A, B], np.r_[np.zeros(27, int), np.ones(27, int)], [0, 1],
                               [[0, 0, 0.5], [3, 0, 0.5]], [[0.6] * 3] * 2, [0.0, 0.0])
Q = np.sqrt(0.9)  # a perfect cuboid's pairwise quality at confidence 0.9


def score(points, instance, label, conf):
    tally = field.tally_of(TRUTH, points, instance, label, conf)
    return field.values(tally, TRUTH, field.FIELD_METRICS)


def perfect():
    return np.r_[A, B], np.r_[np.zeros(27, int), np.ones(27, int)], {0: 0, 1: 1}, {0: 0.9, 1: 0.9}


def check(v, **expected):
    for name, want in expected.items():
        assert v[name] == pytest.approx(want, abs=1e-6), name


def test_perfect_map_scores_one_everywhere_its_labels_allow():
    v = score(*perfect())
    check(v, omq=Q, omq_pairwise=Q, omq_label=0.9, omq_spatial=1.0, omq_fp_quality=1.0, ap=1.0, ap50=1.0, ap25=1.0,
          miou=1.0, macc=1.0, fmiou=1.0)
    for name in field.OBJECTS:
        check(v, **{name: 1.0})
    for tau in ("5cm", "20cm"):
        check(v, **{f"accuracy_{tau}": 1.0, f"completeness_{tau}": 1.0, f"fscore_{tau}": 1.0, f"chamfer_{tau}": 0.0})
        assert v[f"chamfer_{tau}"] >= 0.0  # never a rounding error below 0


def test_one_object_missing():
    v = score(A, np.zeros(27, int), {0: 0}, {0: 0.9})
    check(v, omq=Q / 2, omq_pairwise=Q, ap=0.5, ap50=0.5, ap25=0.5, precision25=1.0, recall25=0.5, f1_25=2 / 3,
          accuracy_5cm=1.0, completeness_5cm=0.5, fscore_5cm=2 / 3, chamfer_5cm=0.0, completeness_20cm=0.5,
          miou=0.5, macc=0.5, fmiou=0.5)


def test_merged_pair():
    # one instance over both: surface IoU 27 / 54 with each; its cuboid 3.6 x 0.6 x 0.6 holds A's box (1/6)
    v = score(np.r_[A, B], np.zeros(54, int), {0: 0}, {0: 0.9})
    check(v, omq=np.sqrt(0.9 / 6) / 2, omq_spatial=1 / 6, ap=0.0, ap50=0.0, ap25=0.5,  # IoU 0.5 is not > 0.5
          precision25=1.0, recall25=0.5, precision50=1.0, recall50=0.5,  # P/R count IoU >= threshold
          precision_weak=0.0, recall_weak=0.0, f1_weak=0.0,  # its centroid (1.5, 0, 0.5) lies in neither box
          accuracy_5cm=1.0, completeness_5cm=1.0, miou=0.25, macc=0.5, fmiou=0.25)


def test_split_object():
    # A split: its two lower layers (18 samples, conf 0.9) and its top layer (9, conf 0.95), a flat cuboid
    low, top = A[:, 2] < 0.6, A[:, 2] > 0.6
    pts = np.r_[A[low], A[top], B]
    inst = np.r_[np.zeros(18, int), np.ones(9, int), np.full(27, 2)]
    v = score(pts, inst, {0: 0, 1: 0, 2: 1}, {0: 0.9, 1: 0.95, 2: 0.9})
    # class 0: AP 0.25 at 0.50-0.65 (the higher-ranked top layer is a false positive), 0 above; class 1: 1
    check(v, ap=(4 * 0.25 / 9 + 1) / 2, ap50=(0.25 + 1) / 2, ap25=1.0,
          omq=(np.sqrt(0.5 * 0.9) + Q) / (2 + 0.95), omq_spatial=0.75, omq_fp_quality=0.05,
          precision25=2 / 3, recall25=1.0, f1_25=0.8, precision50=2 / 3, recall50=1.0)


def test_wrong_label():
    v = score(np.r_[A, B], np.r_[np.zeros(27, int), np.ones(27, int)], {0: 1, 1: 1}, {0: 0.9, 1: 0.9})
    check(v, ap=0.375, ap50=0.375, ap25=0.375, omq=Q / 2.9, omq_fp_quality=0.1, precision25=0.5, recall25=0.5,
          miou=0.25, macc=0.5, fmiou=0.25, accuracy_5cm=1.0, completeness_5cm=1.0)


def test_duplicate_instance():
    pts, inst, label, conf = perfect()
    v = score(np.r_[pts, A], np.r_[inst, np.full(27, 2)], {**label, 2: 0}, {**conf, 2: 0.5})
    # ScanNet's AP: the duplicate is a false positive ranked below the true one (AP stays 1)
    check(v, ap=1.0, omq=2 * Q / 2.5, omq_fp_quality=0.5, precision25=2 / 3, recall25=1.0, f1_25=0.8,
          accuracy_5cm=1.0, completeness_5cm=1.0, chamfer_5cm=0.0, miou=1.0)


def test_map_shifted_beyond_tau():
    pts, inst, label, conf = perfect()
    v = score(pts + [0.0, 0.0, 1.0], inst, label, conf)
    check(v, omq=0.0, omq_fp_quality=0.1, ap=0.0, ap25=0.0, precision25=0.0, recall_weak=0.0, accuracy_5cm=0.0,
          completeness_20cm=0.0, fscore_20cm=0.0, chamfer_5cm=0.1, chamfer_20cm=0.4, miou=0.0, fmiou=0.0)


def test_empty_map_has_a_value_for_every_metric():
    v = score(np.zeros((0, 3)), np.zeros(0, int), {}, {})
    assert set(v) == set(field.FIELD_METRICS) and all(np.isfinite(list(v.values())))
    check(v, omq=0.0, omq_fp_quality=1.0, ap=0.0, precision25=0.0, recall25=0.0, f1_25=0.0, accuracy_5cm=0.0,
          completeness_5cm=0.0, chamfer_5cm=0.1, chamfer_20cm=0.4, miou=0.0)


def test_unlabelled_instances_are_geometry_only_and_tiny_ones_have_no_cuboid():
    pts, inst, _, _ = perfect()
    v = score(pts, inst, {0: -1, 1: -1}, {0: 0.0, 1: 0.0})
    check(v, omq=0.0, omq_fp_quality=1.0, precision25=0.0, recall25=0.0, accuracy_5cm=1.0, completeness_5cm=1.0,
          miou=0.0)
    v = score(A[:3], np.zeros(3, int), {0: 0}, {0: 1.0})  # 3 points: no cuboid, so no spatial quality
    check(v, omq=0.0, omq_fp_quality=0.0)
    # 2- and 3-point instances with their centroids at the objects' centres: no cuboid, so
    # neither the weak nor the strict containment matches them (4 points do)
    for n, want in ((2, 0.0), (3, 0.0), (4, 1.0)):
        pts = np.array([[0.0, -0.1, 0.5], [0.0, 0.1, 0.5], [0.0, 0.0, 0.4], [0.0, 0.0, 0.6]])[:n]
        pts = np.r_[pts, pts + [3.0, 0.0, 0.0]]
        v = score(pts, np.r_[np.zeros(n, int), np.ones(n, int)], {0: 0, 1: 1}, {0: 1.0, 1: 1.0})
        check(v, precision_weak=want, recall_weak=want, precision_strict=want, recall_strict=want)


def test_kernels_by_hand():
    # a unit cube against itself turned 45 degrees: octagon of area 2(sqrt 2 - 1) -> IoU 0.8284 / 1.1716
    inter = 2 * (np.sqrt(2) - 1)
    assert box_iou(np.zeros(3), np.ones(3), np.full(3, 0.5), np.ones(3), np.pi / 4) == pytest.approx(inter / (2 - inter))
    assert box_iou(np.zeros(3), np.ones(3), np.array([0.5, 0.5, 1.5]), np.ones(3), 0.0) == 0.0
    # ScanNet: a true positive ranked above a false one gives AP 1; below it, 0.25
    iou = np.array([[0.9], [0.0]])
    assert class_ap(iou, np.array([0.9, 0.5]), 0.5) == pytest.approx(1.0)
    assert class_ap(iou, np.array([0.5, 0.9]), 0.5) == pytest.approx(0.25)
    assert class_ap(np.zeros((0, 1)), np.zeros(0), 0.5) == 0.0


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(0, 53), min_size=1, max_size=54, unique=True), st.integers(0, 2 ** 31 - 1),
       st.integers(2, 3))
def test_invariant_to_point_order_and_density(keep, seed, copies):
    """Permuting the points (ids with them) changes no metric; repeating every point changes
    none but those that need a cuboid (OMQ's, the weak and strict matches), where an
    instance of under 4 points may reach the 4 a cuboid needs."""
    rng = np.random.default_rng(seed)
    pts = np.r_[A, B][keep] + rng.normal(0, 0.02, (len(keep), 3))
    inst = rng.integers(0, 3, len(keep))
    label, conf = {0: 0, 1: 1, 2: 0}, {0: 0.9, 1: 0.8, 2: 0.7}
    base = score(pts, inst, label, conf)
    order = rng.permutation(len(keep))
    small = np.bincount(inst).min() < field.MIN_BOX_POINTS
    for v, names in ((score(pts[order], inst[order], label, conf), field.FIELD_METRICS),
                     (score(np.repeat(pts, copies, 0), np.repeat(inst, copies), label, conf),
                      [n for n in field.FIELD_METRICS
                       if not (small and (n in field.OMQ or n.endswith(("_weak", "_strict"))))])):
        for name in names:
            assert v[name] == pytest.approx(base[name], abs=1e-9), name


def test_a_growing_map_scores_as_from_nothing():
    rng = np.random.default_rng(0)
    pts = np.r_[A, B] + rng.normal(0, 0.03, (54, 3))
    inst = rng.integers(0, 4, 54)
    label, conf = np.array([0, 1, 0, 1]), np.array([0.9, 0.8, 0.7, 0.6])
    scorer = field.FieldScorer(TRUTH)
    for end in (10, 30, 54):
        whole = field.tally_of(TRUTH, pts[:end], inst[:end], label, conf)
        ids = np.unique(inst[:end])
        shared = np.zeros((4, 2), np.int64)
        shared[ids] = whole.shared
        sample = field.tally_of.__globals__["cKDTree"](TRUTH.samples).query(pts[:end], distance_upper_bound=0.05)[1]
        grown = scorer.tally(pts[:end], inst[:end], label, conf, np.where(sample < 54, sample, -1), shared)
        got, want = field.values(grown, TRUTH, field.FIELD_METRICS), field.values(whole, TRUTH, field.FIELD_METRICS)
        for name in field.FIELD_METRICS:  # the Chamfer's running sums may round otherwise in the last digit
            assert got[name] == pytest.approx(want[name], rel=1e-12, abs=1e-15), name


def test_a_sessions_map_metric_curves_end_at_what_evaluate_gives_its_exported_map(tmp_path):
    """The built-in knowledge's map over time (each sample's first-observed step) ends as the
    exported map: its final field and task values are evaluate's of that map; defaults add none."""
    import pandas as pd

    from rosmeery_jax.apps.cli import main
    from rosmeery_jax.metrics.tasks import TASK_METRICS

    out = tmp_path / "run"
    assert main(["run", "--worlds", "small_office", "--seeds", "2", "--detector", "off", "--duration", "6", "--quiet",
                 "--policies", "frontier", "--metrics", "ori,field,task", "--out", str(out)]) == 0
    df = pd.read_csv(out / "metrics.csv")
    assert set(df.metric) == {"ori", *field.FIELD_METRICS, *TASK_METRICS} and np.isfinite(df.value).all()
    for seed in (0, 1):
        run = df[df.seed == seed]
        final = run[run.time_s == run.time_s.max()].set_index("metric").value
        ev = tmp_path / f"eval{seed}"
        ply = out / "maps" / f"small_office__frontier__seed{seed}.ply"
        assert main(["evaluate", "--world", "small_office", "--map", str(ply), "--out", str(ev), "--metrics",
                     "ori,field,task"]) == 0
        ours = pd.read_csv(ev / "metrics.csv").set_index("metric").value
        for metric in ("ori", *field.FIELD_METRICS, *TASK_METRICS):
            assert final[metric] == pytest.approx(ours[metric], abs=1e-6), metric
        assert final["completeness_5cm"] > 0 and final["accuracy_5cm"] == 1.0  # its points are samples
        first = run[run.time_s == run.time_s.min()].set_index("metric").value
        assert first["completeness_20cm"] <= final["completeness_20cm"]
        assert first["task_success"] == 0 and final["task_success"] > 0  # nothing seen yet: no goal found
