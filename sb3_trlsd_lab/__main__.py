"""``python -m sb3_trlsd_lab`` is the ``sb3-trlsd`` command."""

from sb3_trlsd_lab.cli import main

raise SystemExit(main())
