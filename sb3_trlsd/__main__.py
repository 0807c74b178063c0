"""``python -m sb3_trlsd`` is the ``sb3-trlsd`` command."""

from sb3_trlsd.cli import main

raise SystemExit(main())
