"""``python -m capsmech.cli``: the same as the ``capsmech`` command."""
from capsmech.cli.main import main

raise SystemExit(main())
