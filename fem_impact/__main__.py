"""``python -m fem_impact`` runs the command line."""

from .cli import main

raise SystemExit(main())
