"""``python -m sb3_trlsd_lab`` is the ``sb3-trlsd`` command."""

from sb3_trlsd_lab.console import main

raise SystemExit(main())
