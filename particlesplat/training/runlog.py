"""A run's ``metrics.jsonl``: one JSON object a line, appended as training goes.

A crash or a full disk can leave the last line half written. Reading tolerates exactly that (the torn
last line is reported and left out); any other line that is not a JSON object is an error naming the
file and the line.
"""

from __future__ import annotations

import json
from os import PathLike
from pathlib import Path

from particlesplat.core.errors import UserError, one_line


class LogError(UserError):
    """A metrics log line that is not a JSON object (other than a torn last line)."""


def read_log(path: str | PathLike) -> tuple[list[dict], str | None]:
    """The records of a metrics log and, when its last line is torn, a one-line note naming the file and
    the line (the torn line is left out of the records). LogError for a bad line before the last."""
    path = Path(path)
    data = path.read_bytes()
    lines = data.split(b"\n")
    if lines and lines[-1] == b"":
        lines.pop()  # the newline that ends the last record
    complete = data.endswith(b"\n")
    records: list[dict] = []
    note = None
    for i, raw in enumerate(lines):
        if not raw.strip():
            continue
        try:
            rec = json.loads(raw)
            if not isinstance(rec, dict):
                raise ValueError(f"a JSON {type(rec).__name__}, not an object")
        except (ValueError, RecursionError) as e:
            if i == len(lines) - 1:
                note = (
                    f"{path}: line {i + 1} is {'torn' if not complete else 'not a JSON object'} "
                    f"({one_line(e, 80)}); left out"
                )
                break
            raise LogError(f"{path}: line {i + 1}: not a JSON object ({one_line(e, 80)})") from None
        records.append(rec)
    return records, note
