"""Entry point for ``python -m avoidd``."""

from avoidd.cli import main

raise SystemExit(main())
