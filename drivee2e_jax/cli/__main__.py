"""``python -m drivee2e_jax.cli`` == ``drivee2e``."""

from drivee2e_jax.cli import main

raise SystemExit(main())
