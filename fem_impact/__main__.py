"""``python -m fem_impact`` runs the command line."""

from .app.cli import main

raise SystemExit(main())
