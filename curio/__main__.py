"""Allow ``python -m curio``."""

from curio.cli import main

raise SystemExit(main())
