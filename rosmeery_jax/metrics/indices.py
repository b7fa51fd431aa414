"""Metrics over time, computed from per-object logs (docs/metrics.md), and their registry.

Every metric is a function ``fn(log, truth) -> curve``: ``log`` an :class:`ObjectLog` whose
fields are (..., T, N) (leading axes for envs), ``truth`` a :class:`GroundTruthTable`;
the curve is (..., T). They are written with ``jax.numpy`` so they differentiate (soft
coverage) and run on numpy input too. Register your own with ``@register("name")``; a
session picks its active set by name.

Built in:
- ``ori``: 1 - min(1, mean_n |ps_G - ps_t| / ps_G)                        (paper Eq. 3)
- ``cori``: the same with c_t(n) ps_t(n), c_t the held label's confidence when it is n's
  category, else 0 (Eq. 4)
- ``cori_any``: label-agnostic cORI: the best confidence of any label
- ``opi``: 1 - min(1, mean_n |P_G - p_t| / P_G), p_t predicates declared   (Eq. 5)
- ``opi_strict``: only correct predicates count and each false one adds an error:
  1 - min(1, mean_n (|P_G - correct_t| + (p_t - correct_t)) / P_G)
"""

from __future__ import annotations

from functools import partial
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax.core import plugins, specs
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.metrics.field import FIELD_METRICS, FIELD_SET
from rosmeery_jax.metrics.tasks import TASK_METRICS, TASK_SET

MAP_METRICS = FIELD_METRICS + TASK_METRICS  # scored from maps, not from object logs
from rosmeery_jax.sim.knowledge import GroundTruthTable, ObjectLog

MetricFn = Callable[[ObjectLog, GroundTruthTable], "jnp.ndarray"]
REGISTRY: dict[str, MetricFn] = {}
PLUGIN_SPECS: dict[str, str] = {}  # name -> the plugin entry that registered it (named in its errors)
CHECKED: dict[str, MetricFn] = {}  # name -> the function that passed _check_curve (a plugin, or yours)
DEFAULT_METRICS = ("ori", "cori", "cori_any", "opi", "opi_strict")


def register(name: str) -> Callable[[MetricFn], MetricFn]:
    """Decorator: make ``fn(log, truth) -> (..., T)`` available as metric ``name`` (a plain
    name: the results' plots are named after it)."""
    if not specs.label_name(name):
        raise InputError("register_metric", "name", f"{name!r} is not a plain name ({specs.LABEL_RULE})")

    def add(fn: MetricFn) -> MetricFn:
        if name in MAP_METRICS or name in (FIELD_SET, TASK_SET) or (name in DEFAULT_METRICS and name in REGISTRY):
            # your own may be re-registered (a notebook cell re-run)
            raise InputError("register_metric", "name", f"{name!r} is a built-in metric: name yours otherwise")
        if not callable(fn):
            raise TypeError(f"register_metric({name!r}) decorates a function fn(log, truth) -> curve, not "
                            f"{type(fn).__name__}")
        REGISTRY[name] = fn
        return fn

    return add


def _index(errors, weights):
    """1 - min(1, mean over objects of errors / weights). errors (..., T, N), weights (N,)."""
    return 1.0 - jnp.minimum(1.0, jnp.mean(errors / weights, axis=-1))


def _reconstruction(weighted_ps, truth: GroundTruthTable):
    """ORI-style index of (possibly confidence-weighted) observed samples (..., T, N)."""
    g = jnp.asarray(truth.ps_G, jnp.float32)
    return _index(jnp.abs(g - weighted_ps), g)


@register("ori")
def ori(log: ObjectLog, truth: GroundTruthTable):
    return _reconstruction(log.ps, truth)


@register("cori")
def cori(log: ObjectLog, truth: GroundTruthTable):
    return _reconstruction(log.conf_true * log.ps, truth)


@register("cori_any")
def cori_any(log: ObjectLog, truth: GroundTruthTable):
    return _reconstruction(log.conf_any * log.ps, truth)


@register("opi")
def opi(log: ObjectLog, truth: GroundTruthTable):
    p = jnp.asarray(truth.P_G, jnp.float32)
    return _index(jnp.abs(p - log.declared), p)


@register("opi_strict")
def opi_strict(log: ObjectLog, truth: GroundTruthTable):
    p = jnp.asarray(truth.P_G, jnp.float32)
    false = log.declared - log.correct
    return _index(jnp.abs(p - log.correct) + false, p)


def expand(names) -> tuple[str, ...]:
    """``names`` with each set name (``field``, ``task``) replaced by its metrics, each once."""
    sets = {FIELD_SET: FIELD_METRICS, TASK_SET: TASK_METRICS}
    return tuple(dict.fromkeys(m for n in names for m in sets.get(n, (n,))))


def resolve(names) -> tuple[str, ...]:
    """Check metric names against the registry (one-line error for an unknown one); a
    plugin ``FILE.py:fn`` or ``package.module:fn`` is loaded, checked and registered as
    ``fn``, the name its curves carry in the results. ``field`` stands for every field
    map metric (:mod:`.field`) and ``task`` for every map-use metric (:mod:`.tasks`), which
    are scored from maps, not from object logs."""
    out = []
    for n in expand(names):
        if n in MAP_METRICS:
            out.append(n)
            continue
        if n not in REGISTRY and specs.is_plugin(n):
            n = _register_plugin(n)
        if n not in REGISTRY:
            raise InputError("config", "metrics", f"unknown metric {n!r} (registered: {', '.join(sorted(REGISTRY))}; "
                             f"the map metrics: {FIELD_SET}, {TASK_SET} or one of them, docs/metrics.md; or a plugin "
                             "FILE.py:function)")
        if n not in DEFAULT_METRICS and CHECKED.get(n) is not REGISTRY[n]:  # registered in Python: checked once
            _check_curve(REGISTRY[n], _named(n))
            CHECKED[n] = REGISTRY[n]
        out.append(n)
    return tuple(out)


def _register_plugin(spec: str) -> str:
    """Load the metric function ``spec`` names, check it (:func:`_check_curve`), register it."""
    fn = plugins.load(spec, "config", "metrics")
    name = spec.rsplit(":", 1)[1]
    if not callable(fn):
        raise InputError("config", "metrics", f"plugin {spec!r} is not a function fn(log, truth) -> curve")
    if name in REGISTRY and REGISTRY[name] is not fn:
        raise InputError("config", "metrics", f"plugin {spec!r}: a metric named {name!r} exists already")
    _check_curve(fn, f"plugin {spec!r}")
    REGISTRY[name] = CHECKED[name] = fn
    PLUGIN_SPECS[name] = spec
    return name


def _check_curve(fn, who: str) -> None:
    """``fn`` traces under JAX on a small log (T = 3 steps, N = 2 objects) and gives a curve
    (3,) of floats, finite on a log of nothing seen, a log of some things seen and labelled
    and one of everything (:func:`_sample_log`); else one InputError naming it as ``who``."""
    f32, i32 = jax.ShapeDtypeStruct((3, 2), jnp.float32), jax.ShapeDtypeStruct((3, 2), jnp.int32)
    log = ObjectLog(f32, f32, f32, i32, i32, i32)
    truth = GroundTruthTable(np.full(2, 4.0, np.float32), np.full(2, 2, np.int32), np.arange(2, dtype=np.int32))
    try:
        curve = jax.eval_shape(lambda lg: fn(lg, truth), log)
    except Exception as err:
        raise InputError("config", "metrics", f"{who} cannot run under JAX on an object log: "
                         f"{type(err).__name__}: {str(err).splitlines()[0][:200] if str(err) else ''}") from None
    if not hasattr(curve, "shape") or curve.shape != (3,) or not jnp.issubdtype(curve.dtype, jnp.floating):
        gave = f"{curve.dtype} values of shape {curve.shape}" if hasattr(curve, "shape") else type(curve).__name__
        raise InputError("config", "metrics", f"{who} must return one float per step, shape (T,); "
                         f"for T = 3 it gave {gave}")
    for seen in ("nothing", "part", "all"):
        with plugins.raised_by(who, "metrics", f"a log of {seen} seen", who):
            values = np.asarray(jax.jit(fn)(_sample_log(seen), truth))
        if not np.isfinite(values).all():
            raise InputError("config", "metrics", f"{who} gave {values.tolist()} on a log of {seen} seen: a curve "
                             "must be finite numbers")


def _sample_log(seen: str) -> ObjectLog:
    """A log of T = 3 steps and N = 2 objects of 4 samples and 2 predicates each, categories
    0 and 1: nothing seen, part of each seen and labelled (one right, one wrong), or all."""
    ps = {"nothing": [[0, 0]] * 3, "part": [[0, 0], [1, 2], [2, 3]], "all": [[4, 4]] * 3}[seen]
    ps = np.asarray(ps, np.float32)
    known = ps > 0
    conf = np.where(known, 0.8, 0.0).astype(np.float32)
    label = np.where(known, [[0, 0]], -1).astype(np.int32)
    declared = np.where(known, 2, 0).astype(np.int32)
    return ObjectLog(ps, np.where(label == [[0, 1]], conf, 0.0).astype(np.float32), conf, label, declared,
                     np.where(label == [[0, 1]], declared, 0).astype(np.int32))


def compute(log: ObjectLog, truth: GroundTruthTable, names=DEFAULT_METRICS) -> dict[str, np.ndarray]:
    """{metric name: (..., T) float64 numpy curve} for the chosen metrics that are scored
    from object logs (the field map metrics among ``names`` are left out), in one compiled
    call per shape (op by op, a session paid a compile of every operation for every world)."""
    log, truth = _arrays(log, truth)
    names = tuple(n for n in resolve(names) if n not in MAP_METRICS)
    curves = _curves(log, truth, names)  # a jitted dict comes back in sorted key order
    for n in names:  # checked on T = 3 steps when registered: a curve may depend on T
        if np.shape(curves[n]) != log.ps.shape[:-1]:
            raise InputError("config", "metrics", f"{_named(n)} gave a curve of shape {np.shape(curves[n])} for a log "
                             f"of {log.ps.shape[:-1]} steps: one value per step is needed")
        bad = np.flatnonzero(~np.isfinite(np.asarray(curves[n]).reshape(-1)))
        if len(bad):  # before any file holds it: a results table holds finite numbers only
            value = np.asarray(curves[n]).reshape(-1)[bad[0]]
            raise InputError("config", "metrics", f"{_named(n)} gave {value} at step {bad[0] % log.ps.shape[-2]} "
                             f"of a log of {log.ps.shape[-2]} steps: a curve must be finite numbers")
    return {n: np.asarray(curves[n], np.float64) for n in names}


def _named(name: str) -> str:
    """A metric as its errors name it: the plugin entry, or the name it was registered by."""
    return f"plugin {PLUGIN_SPECS[name]!r}" if name in PLUGIN_SPECS else f"metric {name!r}"


def _arrays(log, truth) -> tuple[ObjectLog, GroundTruthTable]:
    """``log`` and ``truth`` as numpy, or a clear error: every log field of one shape, (..., T,
    N) or one step's (N,); every truth field (N,) (one object's truth would broadcast over any N)."""
    for name, arg, kind in (("log", log, ObjectLog), ("truth", truth, GroundTruthTable)):
        if not isinstance(arg, tuple) or len(arg) != len(kind._fields):
            raise TypeError(f"compute_metrics: {name} must be {kind.__name__}({', '.join(kind._fields)}), "
                            f"not {type(arg).__name__}")
    log = ObjectLog(*(np.asarray(a) for a in log))
    truth = GroundTruthTable(*(np.asarray(a) for a in truth))
    shape = log.ps.shape
    for field, a in zip(ObjectLog._fields, log):
        if a.shape != shape or a.ndim < 1:
            raise ValueError(f"compute_metrics: log.{field} has shape {a.shape}: every field must be "
                             f"(..., N) like log.ps {shape}")
    for field, a in zip(GroundTruthTable._fields, truth):
        if a.shape != shape[-1:]:
            raise ValueError(f"compute_metrics: truth.{field} has shape {a.shape}: the log holds "
                             f"N = {shape[-1]} objects")
    return log, truth


@partial(jax.jit, static_argnums=2)
def _curves(log: ObjectLog, truth: GroundTruthTable, names: tuple[str, ...]) -> dict:
    return {n: _curve(n, log, truth) for n in names}


def _curve(name: str, log: ObjectLog, truth: GroundTruthTable):
    """One metric's curve; a metric of yours that raises is one line naming it and its line
    (it passed the check on a log of 3 steps, and may fail on the session's)."""
    if name in DEFAULT_METRICS:
        return REGISTRY[name](log, truth)
    with plugins.raised_by(name, "metrics", f"its curve of {log.ps.shape[-2]} steps", _named(name)):
        return REGISTRY[name](log, truth)


def summarize(times: np.ndarray, curve: np.ndarray) -> dict[str, float]:
    """Summary figures of one curve (T,) over times (T,) in seconds: final value; area under
    the curve divided by the duration (the curve's time average, in [0, 1]); first time the
    curve reaches 50% and 90% of its final value (NaN when the final value is 0)."""
    times, curve = np.asarray(times, float), np.asarray(curve, float)
    if times.ndim != 1 or times.shape != curve.shape or not len(times):
        raise ValueError(f"summarize: times {times.shape} and curve {curve.shape} must be one non-empty (T,) each")
    if (np.diff(times) < 0).any() or not np.isfinite(times).all():
        raise ValueError("summarize: times must be finite and in increasing order")
    final = float(curve[-1])
    span = times[-1] - times[0]
    auc = float(np.trapezoid(curve, times) / span) if span > 0 else final
    out = {"final": final, "auc": auc}
    for frac in (0.5, 0.9):
        key = f"t{int(frac * 100)}_s"
        if not final > 0:  # 0 or NaN: no fraction of it is reached
            out[key] = float("nan")
        else:
            out[key] = float(times[np.argmax(curve >= frac * final - 1e-12)])
    return out
