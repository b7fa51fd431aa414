"""Sessions on a Ray cluster: one task per unfinished run, the driver writes the results.

A *shard* is one (world, policy) run with all its seeds. Each shard is a Ray task that runs
the ordinary session engine on its run alone, in a scratch folder on the worker, and
returns the run's files; the driver writes them atomically into the results folder (the
metrics file last, as a local session does), so workers need no shared filesystem and a
half-finished shard leaves nothing behind. A shard's results are bitwise those of the same
run inside a local session: a run does not depend on the other runs of its batch nor on
the padding (rosmeery_jax.session.batch). Ray retries a shard whose worker dies (``RETRIES``);
``--resume`` skips finished runs as locally. docs/cluster.md covers set-up and costs.
"""

from __future__ import annotations

import importlib.util
import os
import secrets
import socket
import sys
from pathlib import Path
from typing import Callable

from rosmeery_jax.core.errors import InputError
from rosmeery_jax.core.files import write_atomic
from rosmeery_jax.results.manifest import RUN_SUFFIX

RETRIES = 3  # attempts after the first when a worker process or node dies
CONNECT_TIMEOUT_S = 10.0  # a head that does not accept a connection by then is not there
INSTALL = "pip install 'rosmeery-jax[cluster]'"


def require_ray() -> None:
    """One InputError naming the extra to install if Ray is missing (found, not imported:
    Ray reads its authentication settings when it is imported, :func:`connect` sets them)."""
    try:
        found = importlib.util.find_spec("ray") is not None
    except ValueError:  # ray in sys.modules without a spec (a test's stand-in)
        found = False
    if not found or sys.modules.get("ray", False) is None:
        raise InputError("command line", "--cluster", f"needs Ray: {INSTALL}")


def check_address(address: str) -> None:
    """Refuse an address that cannot be a cluster, or whose head does not answer within
    ``CONNECT_TIMEOUT_S`` (Ray itself would wait for it without end)."""
    if address in ("ray", "auto"):
        return
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise InputError(address or '""', "--cluster", "is not ray, auto, ray://HOST:PORT or HOST:PORT")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT_S).close()
    except OSError as err:
        raise InputError(address, "--cluster", f"no Ray head answers there within {CONNECT_TIMEOUT_S:g} s "
                         f"({err.strerror or err})") from None


def _auth(address: str) -> None:
    """Set Ray's authentication for this process (docs/cluster.md), unless RAY_AUTH_MODE is
    set. A local cluster gets token authentication with a token of its own, passed to its
    processes in the environment and written nowhere (Ray would write it to ~/.ray, where a
    later join to another head would pick it up). A join uses token mode when a token is
    at hand (RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token): Ray 2.60 then joins
    heads with and without authentication alike, where it would fail on a token head."""
    if os.environ.get("RAY_AUTH_MODE"):
        return
    if address == "ray":
        os.environ.setdefault("RAY_AUTH_TOKEN", secrets.token_hex(32))
    elif not (os.environ.get("RAY_AUTH_TOKEN") or os.environ.get("RAY_AUTH_TOKEN_PATH") or
              (Path.home() / ".ray" / "auth_token").is_file()):
        return  # Ray's default mode
    os.environ["RAY_AUTH_MODE"] = "token"
    _reread_auth(address)


def _reread_auth(address: str) -> None:
    """Ray reads its authentication settings when it is imported. If it already was (in a
    notebook, by another library), have it read them again, as Ray does itself when it turns
    token authentication on (its configuration and token cache; without this, a local
    cluster's GCS refused the driver: "Failed to start GCS")."""
    if "ray._raylet" not in sys.modules:
        return
    try:
        from ray._raylet import AuthenticationTokenLoader, Config

        Config.initialize("")
        AuthenticationTokenLoader.instance().reset_cache()
    except (ImportError, AttributeError):  # a Ray whose private API moved
        raise InputError(address, "--cluster", "Ray was imported before its authentication could be set: run the "
                         "session in a new process, or set RAY_AUTH_MODE before importing Ray (docs/cluster.md)") from None


def connect(address: str):
    """Join the cluster at ``address``: ``ray`` (a new local one, of this machine's cores),
    ``auto`` (the running one), ``ray://HOST:PORT`` or ``HOST:PORT``."""
    require_ray()
    check_address(address)
    _auth(address)  # before Ray is imported: it reads the mode then
    import ray  # the optional [cluster] extra: imported only when a cluster is asked for

    if not ray.is_initialized():
        kwargs = dict(include_dashboard=False, log_to_driver=False, logging_level="WARNING",
                      address="local" if address == "ray" else address)  # "local": a new one, never another's
        try:
            ray.init(**kwargs)
        except (ConnectionError, RuntimeError, ValueError) as err:
            raise InputError(address, "--cluster", f"cannot join the Ray cluster ({str(err).splitlines()[0]}); "
                             "a cluster with token authentication needs its token: RAY_AUTH_TOKEN or "
                             "RAY_AUTH_TOKEN_PATH (docs/cluster.md)") from None
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
            try:
                files, timing = ray.get(ref)
            except InputError as err:  # a plugin's error in a task: its own line, not Ray's traceback
                for other in pending:
                    ray.cancel(other)
                cause = getattr(err, "cause", err)  # Ray's error wraps the task's own
                raise (cause if isinstance(cause, InputError) else err) from None
            for rel in sorted(files, key=lambda k: k.endswith(RUN_SUFFIX)):  # the record marks the run done
                write_atomic(out / rel, files[rel])
            timings.append(timing)
            bar.update(cfg.duration)
    return timings
