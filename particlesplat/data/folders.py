"""What the user named as scenes, checked before anything heavy loads (no torch): a command's path errors come in
well under a second, with a hint where the user named the dataset root instead of one of its splits."""

from __future__ import annotations

from os import PathLike
from pathlib import Path

TRANSFORMS = "transforms.json"  # the file that makes a folder a scene folder (docs/dataset.md)
SPLITS = ("train", "val", "test", "heldout")  # heldout: the wide robot world's split outside the training ranges
EVAL_SPLITS = SPLITS  # what eval --splits may name of a dataset folder
DEFAULT_EVAL_SPLITS = ("test", "heldout")  # what eval reads of a dataset folder without --splits
# why eval leaves the other splits out unless --splits names them (it says so)
SKIPPED_SPLIT_REASONS = {"train": "the scenes a model is trained on", "val": "the scenes its checkpoint is chosen on"}


def is_scene_folder(path: Path) -> bool:
    """A folder holding ``transforms.json``."""
    return (path / TRANSFORMS).is_file()


def holds_scenes(path: Path) -> bool:
    """A folder with at least one scene folder directly below it (hidden folders do not count)."""
    try:
        return any(not p.name.startswith(".") and is_scene_folder(p) for p in path.iterdir())
    except OSError:
        return False


def check_split_folder(path: str | PathLike, option: str) -> Path:
    """``path`` as a folder of scene folders (a split: ``DATA/test``). FileNotFoundError naming ``option`` when it
    does not exist or holds no scene folder; when it is a dataset root, the message names its splits
    (``--data data/tabletop: a dataset root; evaluate one split, e.g. --data data/tabletop/test``)."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"{option} {p}: no such folder")
    if not p.is_dir():
        raise NotADirectoryError(f"{option} {p}: not a folder (a folder of scene folders is expected)")
    if holds_scenes(p):
        return p
    splits = [s for s in SPLITS if holds_scenes(p / s)]
    if splits:
        best = "test" if "test" in splits else splits[0]
        raise FileNotFoundError(
            f"{option} {p}: a dataset root (splits {', '.join(splits)}); name one split, e.g. {option} {p / best}"
        )
    if is_scene_folder(p):
        raise FileNotFoundError(f"{option} {p}: one scene folder; name the folder that holds it, {option} {p.parent}")
    raise FileNotFoundError(f"{option} {p}: no scene folders (sub-folders with {TRANSFORMS})")


def dataset_splits(path: str | PathLike) -> tuple[str, ...]:
    """The splits (of :data:`SPLITS`, in that order) holding scene folders of the dataset folder ``path``; () when
    ``path`` holds scene folders itself (a split folder), is no folder, or has no split holding scenes."""
    p = Path(path)
    if not p.is_dir() or holds_scenes(p):
        return ()
    return tuple(s for s in SPLITS if holds_scenes(p / s))


def choose_splits(path: str | PathLike, have: tuple[str, ...], requested: str | None, option: str) -> list[str]:
    """The splits of the dataset folder ``path`` (its splits ``have``) that ``eval`` reads: those named in
    ``requested`` (comma-separated, some of :data:`EVAL_SPLITS`, in the order given), else those of
    :data:`DEFAULT_EVAL_SPLITS` it has. One-line FileNotFoundError naming the folder and its splits when one named
    is not there or it has none of the default ones; OptionError naming ``option`` for a name that is no
    evaluation split."""
    from particlesplat.core.errors import OptionError

    listed = f"its splits: {', '.join(have)}"
    if requested is None:
        chosen = [s for s in DEFAULT_EVAL_SPLITS if s in have]
        if not chosen:
            raise FileNotFoundError(
                f"--data {path}: a dataset folder without {' or '.join(DEFAULT_EVAL_SPLITS)} ({listed}); choose with "
                f"{option} {','.join(have)}"
            )
        return chosen
    chosen = list(dict.fromkeys(s.strip() for s in requested.split(",")))  # in order, once each
    bad = [s for s in chosen if s not in EVAL_SPLITS]
    if bad or not chosen:
        raise OptionError(f"{option} must name some of {','.join(EVAL_SPLITS)}, got {requested[:80]!r}")
    missing = [s for s in chosen if s not in have]
    if missing:
        raise FileNotFoundError(
            f"{option} {','.join(chosen)}: --data {path} has no {' or '.join(missing)} split ({listed})"
        )
    return chosen


def skipped_splits_note(path: str | PathLike, have: tuple[str, ...], chosen: list[str]) -> str | None:
    """The line ``eval`` prints about the splits of the dataset folder ``path`` (its splits ``have``) it leaves
    out by default (``chosen`` are the ones it reads): which, why (:data:`SKIPPED_SPLIT_REASONS`) and the
    ``--splits`` that reads every split; None when it reads them all."""
    skipped = [s for s in have if s not in chosen]
    if not skipped:
        return None
    why = "; ".join(f"{s}: {SKIPPED_SPLIT_REASONS.get(s, 'not asked for')}" for s in skipped)
    return f"{path}: not evaluated: {', '.join(skipped)} ({why}); --splits {','.join(have)} evaluates every split"


def check_file(path: str | PathLike | None, option: str, shipped: bool = False) -> None:
    """FileNotFoundError naming ``option`` when ``path`` is given and is no file (None: not given, nothing to
    check). ``shipped``: a checkpoint option, where a shipped model's name (``assets/robot/model.pt``) opens it from
    any directory (:func:`particlesplat.data.families.shipped_model_named`)."""
    if path is None:
        return
    p = Path(path)
    if shipped:
        from particlesplat.data.families import shipped_model_named

        p = shipped_model_named(p) or p
    if not p.exists():
        raise FileNotFoundError(f"{option} {p}: no such file")
    if not p.is_file():
        raise IsADirectoryError(f"{option} {p}: not a file")


def check_existing(path: str | PathLike | None, option: str) -> None:
    """FileNotFoundError naming ``option`` when ``path`` is given and does not exist (a file or a folder)."""
    if path is not None and not Path(path).exists():
        raise FileNotFoundError(f"{option} {path}: no such file or folder")
