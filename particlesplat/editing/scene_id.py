"""What identifies a scene across edit files, autosaves and screenshots: its resolved path and a digest of its
content (a moved or copied scene keeps its digest; two folders of the same name have different ones)."""

from __future__ import annotations

import hashlib
from os import PathLike
from pathlib import Path

CHUNK = 1 << 20  # bytes read at a time


def scene_digest(path: str | PathLike) -> str:
    """sha256 (hex) of a scene: for a folder, every regular file under it in sorted order, each as its relative
    path, its size and its bytes; for a file (a ``.ply``), its bytes. OSError names the path."""
    root = Path(path)
    h = hashlib.sha256()
    files = [root] if root.is_file() else sorted(p for p in root.rglob("*") if p.is_file())
    if not root.exists():
        raise FileNotFoundError(f"{root}: scene not found")
    for p in files:
        rel = p.name if p == root else p.relative_to(root).as_posix()
        h.update(rel.encode("utf-8", "surrogateescape") + b"\0" + str(p.stat().st_size).encode() + b"\0")
        with open(p, "rb") as f:
            while block := f.read(CHUNK):
                h.update(block)
    return h.hexdigest()


def resolved(path: str | PathLike) -> str:
    """The absolute path with symlinks resolved, as edit files and autosaves record a scene."""
    return str(Path(path).expanduser().resolve())


def scene_file_key(path: str | PathLike, family: str | None) -> str:
    """The stem of a scene's own files (edits, autosaves): ``FAMILY-NAME-HASH``, NAME the folder's (or the .ply's
    stem), HASH 8 hex digits of the resolved path's sha256. Two scenes never share it: demo scenes of two families
    with one name differ by family, two folders of one name by path. ``family`` None: "scene" (".ply": "ply")."""
    p = Path(resolved(path))  # a link to a scene names the scene
    kind = family or ("ply" if p.suffix.lower() == ".ply" else "scene")
    name = (p.stem if p.suffix.lower() == ".ply" else p.name) or "scene"
    digest = hashlib.sha256(str(p).encode("utf-8", "surrogateescape")).hexdigest()[:8]
    return f"{kind}-{name}-{digest}"
