"""The benchmark's metrics: ORI, cORI, OPI and their variants over time, their registry
(``metrics.compute``, ``metrics.register``), and the scoring of any semantic map against a
world's ground truth (:mod:`.map_score`)."""

from rosmeery_jax.metrics.indices import (
                                          DEFAULT_METRICS,
                                          REGISTRY,
                                          compute,
                                          cori,
                                          cori_any,
                                          opi,
                                          opi_strict,
                                          ori,
                                          register,
                                          resolve,
                                          summarize,
)

__all__ = ["DEFAULT_METRICS", "REGISTRY", "compute", "cori", "cori_any", "opi", "opi_strict", "ori", "register",
           "resolve", "summarize"]
