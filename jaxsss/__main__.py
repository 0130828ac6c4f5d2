"""``python -m jaxsss``: the command line (see :mod:`jaxsss.cli`)."""

from jaxsss.cli import main

raise SystemExit(main())
