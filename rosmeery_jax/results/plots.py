"""Metric curves in the style of the paper's Figures 4-5: one line per policy (mean over
seeds) with a shaded band of one standard deviation, x = simulated seconds; a perceived
mapper's curve is dashed in its policy's color."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only; no display needed
import io

import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

from rosmeery_jax.core.files import write_atomic
from rosmeery_jax.core.specs import plain_name
from rosmeery_jax.results.tables import METRIC_COLUMNS  # noqa: E402

LABELS = {"ori": "ORI", "cori": "cORI", "cori_any": "cORI (any label)", "opi": "OPI", "opi_strict": "OPI (strict)"}


def mean_std(df: pd.DataFrame) -> pd.DataFrame:
    """Per (world, policy, detector, mapper, metric, time_s): mean and std over seeds."""
    if "mapper" not in df.columns:
        df = df.assign(mapper="oracle")
    g = df.groupby(["world", "policy", "detector", "mapper", "metric", "time_s"])["value"]
    return g.agg(["mean", "std", "count"]).reset_index().fillna({"std": 0.0})


def plot_curves(df: pd.DataFrame, world: str, metric: str, ax=None):
    """Draw one world's metric curves (all policies) on ax; returns the axes."""
    ax = ax or plt.subplots(figsize=(6, 3.6))[1]
    stats = mean_std(df[(df.world == world) & (df.metric == metric)])
    colors = {p: f"C{i}" for i, p in enumerate(sorted(stats.policy.unique()))}
    for (policy, detector, mapper), s in stats.groupby(["policy", "detector", "mapper"]):
        name = policy if detector == "off" else f"{policy} ({detector})"
        name += "" if mapper == "oracle" else f" [{mapper}]"  # one color per policy, dashed when perceived
        line, = ax.plot(s.time_s, s["mean"], color=colors[policy], linestyle="-" if mapper == "oracle" else "--",
                        label=f"{name} (n={int(s['count'].max())})")
        ax.fill_between(s.time_s, (s["mean"] - s["std"]).clip(0, 1), (s["mean"] + s["std"]).clip(0, 1),
                        color=line.get_color(), alpha=0.2, linewidth=0)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(LABELS.get(metric, metric))
    ax.set_ylim(0, 1.02)
    ax.set_title(f"{world}: {LABELS.get(metric, metric)}")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    return ax


def plot_results(df: pd.DataFrame, directory: str | Path) -> list[Path]:
    """Write ``<world>_<metric>.png`` for every world and metric in df into directory
    (``df`` as :func:`load_results` gives it; ``mapper`` may be left out)."""
    if not isinstance(df, pd.DataFrame):
        raise TypeError(f"plot_results: a results table (load_results(folder)), not {type(df).__name__}")
    missing = [c for c in METRIC_COLUMNS if c not in df.columns and c != "mapper"]
    if missing or df.empty:
        raise ValueError(f"plot_results: the table {'lacks ' + ', '.join(missing) if missing else 'has no rows'} "
                         "(a results table: load_results(folder))")
    out = []
    unsafe = [n for n in (*df.world.unique(), *df.metric.unique()) if not plain_name(str(n))]
    if unsafe:  # names become file names: never a path out of ``directory``
        raise ValueError(f"{unsafe[0]!r} is not a plain name")
    for world in sorted(df.world.unique()):
        for metric in sorted(df.metric.unique()):
            fig, ax = plt.subplots(figsize=(6, 3.6))
            plot_curves(df, world, metric, ax)
            fig.tight_layout()
            out.append(save_figure(fig, Path(directory) / f"{world}_{metric}.png"))
    return out


def learning_curve(curve: pd.DataFrame, path: str | Path) -> Path:
    """A training run's curve (rosmeery_jax.rl.ppo): the mean return of the episodes that
    ended in each update, and the policy's entropy, against env-steps."""
    fig, (ret, ent) = plt.subplots(1, 2, figsize=(9, 3.4))
    ret.plot(curve.env_steps, curve["return"], color="C0")
    ret.set_ylabel("episode return")
    ent.plot(curve.env_steps, curve["entropy"], color="C1")
    ent.set_ylabel("policy entropy")
    for ax in (ret, ent):
        ax.set_xlabel("env-steps")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, Path(path))


def save_figure(fig, path: Path) -> Path:
    """Write ``fig`` as a PNG at ``path`` atomically and close it; returns ``path``."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return write_atomic(path, buf.getvalue())
