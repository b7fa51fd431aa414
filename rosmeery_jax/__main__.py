import sys

from rosmeery_jax.apps.cli import main

sys.exit(main())
