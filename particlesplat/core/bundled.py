"""Where bundled data lives: data packages that ``pyproject.toml``'s ``package-dir`` maps from top-level folders
of the checkout (``particlesplat.assets`` from ``assets/``: the shipped models, recipes and demo scenes; the
viewer's ``viewer.shaders`` from ``shaders/``).

Code run from a source checkout without installing it (the checkout on ``PYTHONPATH``) has no such packages;
it reads the checkout's folders instead.
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path

from particlesplat.core.errors import UserError

CHECKOUT = Path(__file__).resolve().parents[2]  # the folder holding particlesplat/ in a source checkout


class BundledDataMissing(UserError):
    """Neither the installed data package nor the checkout's folder exists."""


def data_dir(package: str, folder: str, checkout: Path = CHECKOUT) -> Path:
    """The folder of data package ``package`` if installed, else ``checkout/folder``.

    Raises :class:`BundledDataMissing` naming both when neither exists.
    """
    try:
        return Path(str(importlib.resources.files(package)))
    except ModuleNotFoundError:
        fallback = checkout / folder
        if fallback.is_dir():
            return fallback
    raise BundledDataMissing(
        f"the data package {package} is not installed and {fallback} does not exist: "
        "install ParticleSplat Studio (pip install -e . in its checkout)"
    )


def bundled_assets() -> Path:
    """The shipped models, their recipes and the demo scenes (``assets/``)."""
    return data_dir("particlesplat.assets", "assets")


def recipe_path() -> Path:
    """The bundled recipe (``assets/recipe.yaml`` in the installed ``particlesplat.assets`` package)."""
    return bundled_assets() / "recipe.yaml"
