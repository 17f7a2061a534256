"""``python -m particlesplat.cli``: the ``particlesplat`` command."""

import sys

from particlesplat.cli.main import console_main

sys.exit(console_main())
