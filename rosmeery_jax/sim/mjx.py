"""MuJoCo MJX, imported once with its optional-backend notice silenced.

``mujoco.mjx`` prints "Failed to import warp" to stdout when the optional Warp backend is
absent (harmless on CPU); that line would corrupt ``--json`` output and alarm users.
"""

import contextlib
import io

with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx  # noqa: F401
