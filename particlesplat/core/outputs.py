"""Outputs never replace what a command reads, nor a file of a run another process owns.

Every command names its outputs and its inputs once and calls :func:`guard_outputs` before it works. Each path is
resolved (symbolic links followed, ``..`` removed) and an output is refused in one line (:class:`OutputError`,
exit 2) when

- it is one of the command's inputs (``curve RUN --out RUN/metrics.jsonl``, ``eval --json SCENE/transforms.json``);
- it is an existing file inside an input folder (``render --scene S --out S/rgb/004.png``): a scene or dataset
  folder is read file by file, so any file in it may be an input; a new file there is allowed;
- it is a folder the command replaces (``train --overwrite``) that holds an input (``--init RUN/best.pt``);
- it lies in a run folder whose lock (:mod:`particlesplat.core.runlock`) a live process holds (``model set ...
  --out LOCKED_RUN/last.pt``).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from os import PathLike
from pathlib import Path

from particlesplat.core.errors import UserError
from particlesplat.core.runlock import live_owner

PathArg = str | PathLike | None


class OutputError(UserError):
    """An output that would overwrite an input or a file of a locked run; the message names both."""


def _resolved(path: str | PathLike) -> Path:
    return Path(os.path.abspath(Path(path).expanduser())).resolve()


def _input_paths(path: str | PathLike) -> list[Path]:
    """An input's resolved path; for a relative name under ``assets/`` that does not exist here, also the bundled
    file of that name, which a shipped model's name opens from any directory
    (:func:`particlesplat.data.families.shipped_model_named`)."""
    given = Path(path).expanduser()
    paths = [_resolved(given)]
    if not given.is_absolute() and not given.exists() and given.parts[:1] == ("assets",):
        from particlesplat.core.bundled import BundledDataMissing, bundled_assets

        try:
            paths.append(_resolved(bundled_assets().joinpath(*given.parts[1:])))
        except BundledDataMissing:
            pass
    return paths


def _inside(path: Path, folder: Path) -> bool:
    return path != folder and folder in path.parents


def guard_outputs(
    outputs: Iterable[tuple[str, PathArg]],
    inputs: Iterable[tuple[str, PathArg]],
    replaced_folders: Iterable[tuple[str, PathArg]] = (),
) -> None:
    """OutputError unless every output may be written (see the module's rules).

    ``outputs``: (flag, path) of the files and folders the command writes; ``inputs``: (flag, path) of the files
    and folders it reads; ``replaced_folders``: (flag, folder) whose existing contents the command deletes or
    replaces. None paths are skipped; flags name the options in the message (``--out``, ``RUN``)."""
    ins = [(flag, Path(p), r) for flag, p in inputs if p is not None and str(p) != "" for r in _input_paths(p)]
    outs = [(flag, Path(p), _resolved(p)) for flag, p in outputs if p is not None and str(p) != ""]
    for flag, given, out in outs:
        for in_flag, in_given, inp in ins:
            if out == inp:
                raise OutputError(
                    f"{flag} {given}: is {in_flag} {in_given}, which this command reads; write the output elsewhere"
                )
            if inp.is_dir() and _inside(out, inp) and out.exists():
                raise OutputError(
                    f"{flag} {given}: would replace a file inside {in_flag} {in_given}, which this command reads; "
                    "write the output elsewhere"
                )
        _refuse_locked(flag, given, out)
    for flag, folder in replaced_folders:
        if folder is None:
            continue
        root = _resolved(folder)
        for in_flag, in_given, inp in ins:
            if inp == root or _inside(inp, root):
                raise OutputError(
                    f"{flag} {folder}: holds {in_flag} {in_given}, which this command reads, and its contents are "
                    "replaced; copy the input elsewhere first"
                )


def _refuse_locked(flag: str, given: Path, out: Path) -> None:
    for folder in (out, *out.parents):
        owner = live_owner(folder)
        if owner is not None:
            raise OutputError(
                f"{flag} {given}: lies in the run folder {folder}, in use by {owner.describe()}; wait for that "
                "run to end, or write elsewhere"
            )
