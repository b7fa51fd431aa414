"""The session layer: a benchmark session's configuration (:mod:`.config`), its results
folder and resume guard (:mod:`.folder`), its batch (:mod:`.batch`), compiled functions
(:mod:`.program`), engine (:mod:`.engine`) and worker thread (:mod:`.worker`), the runner
(:mod:`.runner`), its output files (:mod:`.outputs`) and Ray clusters (:mod:`.cluster`)."""

from rosmeery_jax.session.config import SessionConfig, load_config
from rosmeery_jax.session.outputs import merge, run_name
from rosmeery_jax.session.runner import Session

__all__ = ["Session", "SessionConfig", "load_config", "merge", "run_name"]
