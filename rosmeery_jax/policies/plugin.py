"""A researcher's own explorer as a plugin: ``--policies FILE.py:Name`` (or
``package.module:Name``) names a subclass of :class:`~rosmeery_jax.policies.base.Policy`.

It runs like a built-in: batched inside the session's one compiled function, labelled in
the results by its class's ``name``. Before anything is simulated it is checked whole, each
problem one line naming the plugin: it must import, be a Policy with a ``decide`` and a
plain ``name``, trace under JAX, and return a finite target pose (3,) and a policy state of
the structure ``init`` gives.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from rosmeery_jax.core import plugins, specs, xla
from rosmeery_jax.core.errors import InputError
from rosmeery_jax.policies.base import Policy


def plugin_class(spec: str) -> type[Policy]:
    """A plugin policy's class: a subclass of :class:`Policy` whose ``name`` is a plain name."""
    cls = plugins.load(spec, "config", "policies")
    if not (isinstance(cls, type) and issubclass(cls, Policy)):
        raise InputError("config", "policies", f"plugin {spec!r} is not a Policy class (subclass "
                         "rosmeery_jax.Policy and implement decide)")
    if getattr(cls.decide, "__isabstractmethod__", False):
        raise InputError("config", "policies", f"plugin {spec!r} lacks a decide(state, pstate, key) method")
    name = getattr(cls, "name", "")
    if name == Policy.name or not specs.label_name(name):
        raise InputError("config", "policies", f"plugin {spec!r} needs a class attribute name that labels its "
                         f"results: a plain name ({specs.LABEL_RULE})")
    return cls


def check_plugin(spec: str, env, state=None) -> None:
    """Build the plugin for ``env``, reset one robot (or take ``state``, ``env``'s reset,
    shared by the plugins of one config) and run one decision, compiled: any failure, a
    wrong shape or dtype, or a non-finite target is one line."""
    where = ("config", "policies")
    try:
        policy = plugin_class(spec)(env)
    except InputError:
        raise
    except Exception as err:
        raise InputError(*where, f"plugin {spec!r} cannot be built for the world: {plugins.describe(err)}") from None
    key = jax.random.key(0)
    state = xla.jit(env.reset)(key) if state is None else state
    try:
        pstate = policy.init(key)
        target, after = xla.jit(policy.decide)(state, pstate, key)
    except Exception as err:  # a Python error, or code JAX cannot trace
        raise InputError(*where, f"plugin {spec!r} cannot run under JAX: {plugins.describe(err)}") from None
    target = np.asarray(target)
    if not policy.per_step and target.shape != (3,):
        raise InputError(*where, f"plugin {spec!r}: decide returned a target of shape {target.shape}, not (3,) "
                         "(x, y, yaw)")
    if not np.issubdtype(target.dtype, np.floating):
        raise InputError(*where, f"plugin {spec!r}: decide returned {target.dtype} targets, not floats")
    if not np.isfinite(target).all():
        raise InputError(*where, f"plugin {spec!r}: decide returned a target that is not finite ({target})")
    shapes = lambda tree: jax.tree.map(lambda a: (jnp.shape(a), jnp.result_type(a)), tree)  # noqa: E731
    if jax.tree.structure(after) != jax.tree.structure(pstate) or shapes(after) != shapes(pstate):
        raise InputError(*where, f"plugin {spec!r}: decide returned a policy state unlike init's (same structure, "
                         "shapes and dtypes are needed to carry it between decisions)")
