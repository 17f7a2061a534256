"""The one reader of small JSON files (``scene.json``, ``synth.json``, ``edits.json``, a camera chunk, a bundle's
``manifest.json``, a ``.sog``'s ``meta.json`` inside its zip...): at most :data:`MAX_JSON_BYTES` are read (a 600 MB
``scene.json`` is refused after 16 MiB, never loaded whole), UTF-8 checked, and a file that is not JSON, nested too
deeply or too big is one line naming the file. Files and streams (a zip member) are read with the same bound."""

from __future__ import annotations

import json
from os import PathLike
from pathlib import Path
from typing import IO

from particlesplat.core.errors import UserError, one_line

MAX_JSON_BYTES = 16 << 20


class JsonFileError(UserError):
    """A small JSON file that cannot be read: too big, not UTF-8, not JSON, nested too deeply."""


def parse_json(data: bytes | str, where: str, error: type[UserError] = JsonFileError) -> object:
    """The JSON value of ``data``; ``error`` (one line starting with ``where``) when it is not UTF-8 JSON."""
    try:
        return json.loads(data)
    except ValueError as e:  # JSONDecodeError, UnicodeDecodeError, an integer of more than 4,300 digits
        raise error(f"{where}: not valid JSON ({one_line(e, 200)})") from None
    except RecursionError:
        raise error(f"{where}: not valid JSON (nested too deeply)") from None


def read_json_stream(
    f: IO[bytes], where: str, max_bytes: int = MAX_JSON_BYTES, error: type[UserError] = JsonFileError
) -> object:
    """The JSON value of the binary stream ``f`` (an open file, a zip member), reading at most ``max_bytes`` (+1, to
    tell a bigger one); ``error`` starts with ``where`` (the file, or ``ARCHIVE: MEMBER``) when it is bigger, not
    UTF-8 or not JSON."""
    data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        name = where.rsplit("/", 1)[-1].rsplit(": ", 1)[-1]
        raise error(f"{where}: more than the {max_bytes:,} bytes a {name} may have")
    return parse_json(data, where, error)


def read_json(path: str | PathLike, max_bytes: int = MAX_JSON_BYTES, error: type[UserError] = JsonFileError) -> object:
    """The JSON value of the file ``path``, reading at most ``max_bytes`` (+1, to tell a bigger file); ``error``
    names the file when it is bigger, not UTF-8 or not JSON. OSError (missing, unreadable) passes through."""
    path = Path(path)
    with open(path, "rb") as f:
        return read_json_stream(f, str(path), max_bytes, error)
