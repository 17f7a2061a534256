"""``python -m viewer``: ``particlesplat-viewer`` (:func:`viewer.launch.main`)."""

import sys

from viewer.launch import main

sys.exit(main())
