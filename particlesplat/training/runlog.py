"""A run's ``metrics.jsonl``: one JSON object a line, appended as training goes.

A crash or a full disk can leave the last line half written. Reading tolerates exactly that (the torn
last line is reported and left out); any other line that is not a JSON object is an error naming the
file and the line. The log is read line by line (a 1 GB log is never held whole: only the records a reader
keeps are), a line is at most :data:`MAX_LINE_BYTES`, and the fields every reader uses are checked where
they are read (:func:`check_record`): ``step`` a non-negative integer, ``val``'s metrics numbers or null.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from os import PathLike
from pathlib import Path

from particlesplat.core.errors import UserError, one_line, short_repr

MAX_LINE_BYTES = 1 << 20  # a record of the trainer is ~1 KB
VAL_METRICS = ("psnr", "fg_ari")


class LogError(UserError):
    """A metrics log line that is not a JSON object (other than a torn last line), or a record with a bad field."""


class LogReader:
    """Iterate ``(line number, record)`` over a metrics log, streaming; after the loop, :attr:`note` is a one-line
    note naming the file and the line when the last line was torn (and left out), else None."""

    def __init__(self, path: str | PathLike):
        self.path = Path(path)
        self.note: str | None = None

    def __iter__(self) -> Iterator[tuple[int, dict]]:
        with open(self.path, "rb") as f:
            number, raw = 0, f.readline(MAX_LINE_BYTES + 1)
            while raw:
                number += 1
                following = f.readline(MAX_LINE_BYTES + 1)
                last = not following
                if len(raw) > MAX_LINE_BYTES and not raw.endswith(b"\n"):
                    raise LogError(f"{self.path}: line {number}: longer than {MAX_LINE_BYTES:,} bytes")
                if raw.strip():
                    rec = self._parse(raw, number, last)
                    if rec is None:
                        return
                    yield number, rec
                raw = following

    def _parse(self, raw: bytes, number: int, last: bool) -> dict | None:
        try:
            rec = json.loads(raw)  # checked: one bounded line of the run's own log
            if not isinstance(rec, dict):
                raise ValueError(f"a JSON {type(rec).__name__}, not an object")
        except (ValueError, RecursionError) as e:
            detail = "nested too deeply" if isinstance(e, RecursionError) else one_line(e, 80)
            if last:
                torn = "torn" if not raw.endswith(b"\n") else "not a JSON object"
                self.note = f"{self.path}: line {number} is {torn} ({detail}); left out"
                return None
            raise LogError(f"{self.path}: line {number}: not a JSON object ({detail})") from None
        return rec


def check_record(rec: dict, path: Path, number: int) -> dict:
    """``rec`` when its ``step`` (where present) is a non-negative integer and its ``val`` (where present) an object
    whose metrics are numbers or null; LogError naming the file, the line and the field otherwise."""
    where = f"{path}: line {number}"
    if "step" in rec:
        step = rec["step"]
        if isinstance(step, bool) or not isinstance(step, int) or step < 0:
            raise LogError(f"{where}: key 'step' must be a non-negative integer, got {short_repr(step)}")
    if "val" in rec:
        val = rec["val"]
        if not isinstance(val, dict):
            raise LogError(f"{where}: key 'val' must be an object, got {short_repr(val)}")
        if "step" not in rec:
            raise LogError(f"{where}: a 'val' record without its 'step'")
        for key in VAL_METRICS:
            v = val.get(key)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
                raise LogError(f"{where}: key 'val.{key}' must be a number or null, got {short_repr(v)}")
    return rec


def read_log(path: str | PathLike, keep: Callable[[dict], bool] | None = None) -> tuple[list[dict], str | None]:
    """The records of a metrics log (each checked, :func:`check_record`; only those ``keep`` accepts are held) and,
    when its last line is torn, a one-line note naming the file and the line (the torn line is left out).
    LogError for a bad line before the last."""
    reader = LogReader(path)
    records = [rec for n, rec in reader if check_record(rec, reader.path, n) and (keep is None or keep(rec))]
    return records, reader.note
