"""Sessions on a Ray cluster: one task per unfinished run, the driver writes the results.

A *shard* is one (world, policy) run with all its seeds. Each shard is a Ray task that runs
the ordinary session engine on its run alone, in a scratch folder on the worker, and
returns the run's files; the driver writes them atomically into the results folder (the
metrics file last, as a local session does), so workers need no shared filesystem and a
half-finished shard leaves nothing behind. A shard's results are bitwise those of the same
run inside a local session: a run does not depend on the other runs of its batch nor on
the padding (rosmeery_jax.session.engine). Ray retries a shard whose worker dies (``RETRIES``);
``--resume`` skips finished runs as locally. docs/cluster.md covers set-up and costs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.files import write_atomic

RETRIES = 3  # attempts after the first when a worker process or node dies
INSTALL = "pip install 'rosmeery-jax[cluster]'"


def require_ray():
    """The ray module, or one InputError naming the extra to install."""
    try:
        import ray  # the optional [cluster] extra: imported only when a cluster is asked for
    except ImportError:
        raise InputError("command line", "--cluster", f"needs Ray: {INSTALL}") from None
    return ray


def connect(address: str):
    """Join the cluster at ``address``: ``ray`` (a local one, started if none runs),
    ``auto`` (the running one), ``ray://HOST:PORT`` or ``HOST:PORT``."""
    ray = require_ray()
    if not ray.is_initialized():
        kwargs = dict(include_dashboard=False, log_to_driver=False, logging_level="WARNING")
        if address != "ray":
            kwargs["address"] = address
        try:
            ray.init(**kwargs)
        except (ConnectionError, RuntimeError, ValueError) as err:
            raise InputError(address, "--cluster", f"cannot join the Ray cluster ({str(err).splitlines()[0]})") from None
    return ray


def _absolute(world: str) -> str:
    """A world file's absolute path (on the driver, so workers find it wherever they start)."""
    return str(Path(world).resolve()) if Path(world).is_file() else world


def simulate_on_cluster(cfg, todo: list[tuple[str, str]], out: Path, address: str, bar, cache: bool,
                        shard: Callable) -> list[dict]:
    """Run every (world, policy) of ``todo`` as a Ray task ``shard(cfg, world, policy,
    cache) -> ({relative path: bytes}, timing)``; write each finished run's files as it
    arrives. Returns the shards' timings."""
    ray = connect(address)
    task = ray.remote(num_cpus=1, max_retries=RETRIES)(shard)
    pending = {task.remote(cfg, _absolute(w), p, cache): (w, p) for w, p in todo}
    timings = []
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1)
        for ref in done:
            pending.pop(ref)
            files, timing = ray.get(ref)
            last = [k for k in files if k.endswith(".metrics.csv")]
            for rel in sorted(files, key=lambda k: k in last):  # the metrics file marks the run done
                write_atomic(out / rel, files[rel])
            timings.append(timing)
            bar.update(cfg.duration)
    return timings
