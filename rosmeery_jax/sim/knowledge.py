"""Spatial knowledge (SK): what the robot knows about each object, and its per-step log.

Per object n the agent holds: surface coverage (which ground-truth samples its depth camera
has observed), a label with a confidence, c_t(n) (the best confidence among detections whose
label is n's true category: docs/metrics.md) and the label-agnostic best confidence. The
predicates it declares follow from the label it holds, through the taxonomy.

Where labels come from:
- ``attach`` folds in detections (object index, label, confidence), e.g. from the detector
  between chunks of steps. The held label is the one of the most confident detection so far.
- ``label_observed`` is the detector-off rule: once at least ``min_fraction`` of an object's
  samples are observed, it is labelled with its true category, confidence 1.

The per-step :class:`ObjectLog` is everything a metric needs, so a new metric never needs a
new simulation. Shapes: N objects, S samples, C categories; all functions act on one env.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax.raycast.sensors import CameraConfig
from rosmeery_jax.sim import coverage
from rosmeery_jax.sim.coverage import CoverageConfig


@dataclass(frozen=True)
class KnowledgeConfig:
    min_fraction: float = 0.05  # detector off: observed share of samples that names an object
    coverage: CoverageConfig = CoverageConfig()


class Knowledge(NamedTuple):
    """One env's SK. seen (S,) bool (float in soft coverage); label (N,) int32 category index
    or -1, the held label; confidence (N,) its confidence, the best of any label so far."""

    seen: jax.Array
    label: jax.Array
    confidence: jax.Array


class ObjectLog(NamedTuple):
    """Per object at one step (add leading axes for T steps and B envs): ps (N,) observed
    samples; conf_true (N,) cORI's c_t(n), the held label's confidence when that label is n's
    category, else 0 (what a map of the held labels earns); conf_any (N,) the held label's
    confidence, right or wrong; label (N,) int32; declared (N,) predicates declared;
    correct (N,) declared predicates that are true."""

    ps: jax.Array
    conf_true: jax.Array
    conf_any: jax.Array
    label: jax.Array
    declared: jax.Array
    correct: jax.Array


class GroundTruthTable(NamedTuple):
    """Static per-object truth for metrics, as numpy: ps_G (N,), P_G (N,), category (N,)."""

    ps_G: np.ndarray
    P_G: np.ndarray
    category: np.ndarray


@lru_cache(maxsize=64)
def predicate_tables(taxonomy, categories: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(C,) predicates declared per label, and (N, C) how many of those are true of each object.

    The agent labelling n as k declares taxonomy.predicates(n, k); with the category ->
    macro -> root chain, the i-th of them is true when k's and n's chains agree at level i.
    Cached (read-only arrays): a perceived map is scored once per frame with the same tables.
    """
    names = taxonomy.names
    declared = np.array([len(taxonomy.predicates("_", k)) for k in names], np.int32)
    correct = np.zeros((len(categories), len(names)), np.int32)
    for n, cat in enumerate(categories):
        truth = set(p[1:] for p in taxonomy.predicates("_", cat))
        for c, k in enumerate(names):
            correct[n, c] = sum(p[1:] in truth for p in taxonomy.predicates("_", k))
    declared.flags.writeable = correct.flags.writeable = False
    return declared, correct


class SpatialKnowledge:
    """Pure functions over :class:`Knowledge` for one world; vmap over envs.

    The world enters as data (``world_data.WorldData``: samples, true categories, predicate
    tables, padded to a session's sizes); ``truth`` is the host-side table for metrics."""

    def __init__(self, cfg: KnowledgeConfig, camera: CameraConfig, data, truth: GroundTruthTable | None = None):
        self.cfg, self.camera, self.truth = cfg, camera, truth
        self.table = data.samples
        self.true_category, self.ps_G = data.category, data.ps_G
        self.declared, self.correct = data.declared, data.correct

    def init(self) -> Knowledge:
        n = self.table.num_objects
        z = jnp.zeros(n, jnp.float32)
        return Knowledge(coverage.empty(self.table, self.cfg.coverage), jnp.full(n, -1, jnp.int32), z)

    def observe(self, k: Knowledge, pose: jax.Array, depth: jax.Array) -> Knowledge:
        """Fold one depth frame taken at robot pose (3,) into the coverage."""
        return k._replace(seen=coverage.accumulate(k.seen, self.table, self.cfg.coverage, self.camera, pose, depth))

    def attach(self, k: Knowledge, obj: jax.Array, label: jax.Array, conf: jax.Array) -> Knowledge:
        """Fold detections: obj (D,) object index (-1 = none), label (D,) category, conf (D,)."""
        n = self.table.num_objects
        valid = obj >= 0
        idx = jnp.where(valid, obj, n)  # out of range: dropped
        c = jnp.where(valid, conf, 0.0)
        # Held label: the most confident detection so far (ties keep the older label).
        best = jnp.full(n, -1.0).at[idx].max(c, mode="drop")
        winner = jnp.full(n, -1, jnp.int32).at[jnp.where(valid & (c >= best[jnp.clip(obj, 0, n - 1)]), obj, n)].max(
            jnp.arange(obj.shape[0], dtype=jnp.int32), mode="drop")
        take = (winner >= 0) & (best > k.confidence)
        new_label = jnp.where(take, label[jnp.maximum(winner, 0)], k.label)
        new_conf = jnp.where(take, best, k.confidence)
        return Knowledge(k.seen, new_label.astype(jnp.int32), new_conf)

    def label_observed(self, k: Knowledge) -> Knowledge:
        """Detector off: label every object with >= min_fraction observed with its true
        category, confidence 1."""
        ps = coverage.per_object(k.seen, self.table).astype(jnp.float32)
        named = ps >= self.cfg.min_fraction * self.ps_G
        one = jnp.where(named, 1.0, 0.0)
        return Knowledge(k.seen, jnp.where(named, self.true_category, k.label), jnp.maximum(k.confidence, one))

    def log(self, k: Knowledge) -> ObjectLog:
        """The per-object row every metric is computed from."""
        return ObjectLog(coverage.per_object(k.seen, self.table), *self.label_fields(k))

    def label_fields(self, k: Knowledge) -> tuple[jax.Array, ...]:
        """The label part of the log: conf_true, conf_any, label, declared, correct (N,) each
        (``k.seen`` is not read)."""
        has = k.label >= 0
        lab = jnp.maximum(k.label, 0)
        declared = jnp.where(has, self.declared[lab], 0)
        correct = jnp.where(has, jnp.take_along_axis(self.correct, lab[:, None], 1)[:, 0], 0)
        return self.right_confidence(k), k.confidence, k.label, declared, correct

    def right_confidence(self, k: Knowledge) -> jax.Array:
        """cORI's c_t(n) (N,): the held label's confidence when that label is n's category, else
        0, as a map holding these labels is scored (a right label outbid by a wrong one earns
        nothing)."""
        return jnp.where((k.label >= 0) & (k.label == self.true_category), k.confidence, 0.0)
