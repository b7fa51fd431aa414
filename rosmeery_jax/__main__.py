import sys

from rosmeery_jax.cli import main

sys.exit(main())
