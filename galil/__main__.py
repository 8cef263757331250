"""``python -m galil``: the same as the ``galil`` command."""

from __future__ import annotations

from galil.cli import main

raise SystemExit(main())
