"""Where the robot family's inputs come from: MuJoCo, robosuite's asset files and a headless GL.

robosuite is never imported (its ``__init__`` loads numba, opencv and its controllers); only the folder
of its installed package is located, and its MJCF/mesh/texture files are read from there at run time.
Every failure is a :class:`SimSetupError` whose message is one line naming what to install.
"""

from __future__ import annotations

import ctypes.util
import importlib.util
import os
from pathlib import Path

from particlesplat.core.errors import UserError

INSTALL = "pip install mujoco && pip install --no-deps robosuite==1.5.2"
ROBOSUITE_VERSION = "1.5.2"
REQUIRED = (
    "arenas/table_arena.xml",
    "robots/panda/robot.xml",
    "grippers/panda_gripper.xml",
    "bases/rethink_mount.xml",
    "objects/can.xml",
    "objects/bread.xml",
    "objects/cereal.xml",
    "objects/milk.xml",
    "objects/lemon.xml",
    "objects/bottle.xml",
    "textures",
)


class SimSetupError(UserError):
    """The robot family cannot run here (missing extra, missing asset files or no headless GL); one line
    naming what to install."""


def assets_dir(override: str | os.PathLike | None = None) -> Path:
    """The folder ``robosuite/models/assets`` of the installed robosuite, checked for every file the family
    reads. ``override`` (or ``$PARTICLESPLAT_ROBOSUITE_ASSETS``) names another such folder.

    Raises:
        SimSetupError: robosuite is not installed, or the folder lacks a required file.
    """
    override = override or os.environ.get("PARTICLESPLAT_ROBOSUITE_ASSETS")
    if override:
        root = Path(override)
    else:
        try:
            spec = importlib.util.find_spec("robosuite")
        except (ImportError, ValueError):
            spec = None
        if spec is None or not spec.submodule_search_locations:
            raise SimSetupError(
                f"robot scenes need robosuite {ROBOSUITE_VERSION}'s asset files, which are not installed: "
                f"run '{INSTALL}'"
            )
        root = Path(next(iter(spec.submodule_search_locations))) / "models" / "assets"
    missing = [rel for rel in REQUIRED if not (root / rel).exists()]
    if missing:
        raise SimSetupError(
            f"{root}: robosuite asset folder lacks {missing[0]}"
            + (f" and {len(missing) - 1} more" if len(missing) > 1 else "")
            + f"; reinstall it: '{INSTALL}'"
        )
    return root


def _default_backend() -> str:
    """EGL where ``libEGL`` is found, else OSMesa where ``libOSMesa`` is, else EGL (its error names the fix)."""
    if ctypes.util.find_library("EGL") is None and ctypes.util.find_library("OSMesa") is not None:
        return "osmesa"
    return "egl"


def gl_error(e: BaseException) -> SimSetupError:
    """The one-line error for a MuJoCo that cannot open a headless GL context."""
    return SimSetupError(
        f"MuJoCo cannot open a headless GL context (MUJOCO_GL={os.environ.get('MUJOCO_GL')}: "
        f"{' '.join(str(e).split()) or type(e).__name__}): install 'libegl1 libgl1' (EGL: Mesa or NVIDIA) or "
        "'libosmesa6' with MUJOCO_GL=osmesa"
    )


def import_mujoco():
    """The ``mujoco`` module with a headless GL backend chosen before its import: ``$MUJOCO_GL`` if set,
    else EGL, else OSMesa (:func:`_default_backend`). The backend is fixed for the process once imported.

    Raises:
        SimSetupError: mujoco is not installed, or its GL backend cannot be loaded.
    """
    if importlib.util.find_spec("mujoco") is None:
        raise SimSetupError(f"robot scenes need MuJoCo, which is not installed: run '{INSTALL}'")
    os.environ.setdefault("MUJOCO_GL", _default_backend())
    if os.environ["MUJOCO_GL"] == "egl":
        os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    try:
        import mujoco
    except ImportError as e:
        raise SimSetupError(f"robot scenes need MuJoCo ({e}): run '{INSTALL}'") from e
    except (AttributeError, RuntimeError, OSError) as e:  # what mujoco raises when its GL library is missing
        raise gl_error(e) from e
    return mujoco
