"""The one YAML loader of the project: ``yaml.SafeLoader`` without aliases and duplicate keys.

- Aliases (``*name``) are refused: an alias bomb of a few hundred bytes would otherwise expand
  into gigabytes when a value is printed or walked.
- A key given twice in one mapping is refused instead of silently taking the last value.
- ``1e-4`` is a float (as in YAML 1.2), not the string YAML 1.1 makes of it.
- Documents larger than :data:`MAX_YAML_BYTES` are refused before parsing.
"""

from __future__ import annotations

import re
from os import PathLike
from pathlib import Path
from typing import Any

import yaml

from particlesplat.core.errors import UserError, one_line

MAX_YAML_BYTES = 1 << 20  # 1 MiB: an edits file of ~10,000 particles, far beyond any config


class YamlError(UserError):
    """A YAML document that cannot be loaded; the message names the file, line and column."""


class _Refused(yaml.MarkedYAMLError):
    pass


class _SafeLoader(yaml.SafeLoader):
    """SafeLoader that refuses aliases and duplicate keys."""

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise _Refused(
                None,
                None,
                f"alias '*{one_line(event.anchor, 40)}' is not allowed (write the value out)",
                event.start_mark,
            )
        return super().compose_node(parent, index)

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    duplicate = key in seen
                    seen.add(key)
                except TypeError:
                    continue  # unhashable: the base class reports it
                if duplicate:
                    raise _Refused(None, None, f"key {one_line(repr(key), 80)} is given twice", key_node.start_mark)
        return super().construct_mapping(node, deep)


_SafeLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9][0-9_]*(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"), list("-+0123456789")
)


def _describe(e: yaml.YAMLError) -> str:
    mark = getattr(e, "problem_mark", None)
    problem = getattr(e, "problem", None) or str(e)
    where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
    return where + one_line(problem, 200)


def load_yaml(text: str, where: str) -> Any:
    """Parse one YAML document (safe tags only; no aliases, no duplicate keys).

    Raises :class:`YamlError` naming ``where`` and the line; the message never echoes the document.
    """
    if len(text) > MAX_YAML_BYTES:
        raise YamlError(f"{where}: {len(text)} characters, more than the {MAX_YAML_BYTES} a YAML file may have")
    try:
        return yaml.load(text, Loader=_SafeLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as e:
        raise YamlError(f"{where}: not valid YAML ({_describe(e)})") from None
    except (ValueError, OverflowError) as e:  # e.g. an integer of more than 4300 digits
        raise YamlError(f"{where}: not valid YAML ({one_line(e, 200)})") from None
    except RecursionError:
        raise YamlError(f"{where}: not valid YAML (nested too deeply)") from None


def read_yaml(path: str | PathLike, what: str = "file") -> Any:
    """Read and parse a YAML file with :func:`load_yaml`; a missing or oversized file is an error naming it."""
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_YAML_BYTES:
            raise YamlError(f"{path}: {size} bytes, more than the {MAX_YAML_BYTES} a YAML {what} may have")
        data = path.read_bytes()
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: {what} not found") from None
    except IsADirectoryError:
        raise UserError(f"{path}: is a folder, not a YAML {what}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise YamlError(f"{path}: not UTF-8 text (byte {e.start})") from None
    return load_yaml(text, str(path))
