import sys

from rosmeery_jax.apps import main

sys.exit(main())
