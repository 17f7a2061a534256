"""Command-line arguments before argparse sees them (light to import: no torch, so ``--help`` is quick)."""

from __future__ import annotations

import argparse
import re
from typing import Any

from particlesplat.core.errors import OptionError
from particlesplat.core.yamlsafe import YamlError, load_yaml

_NEGATIVE_NUMBERS = re.compile(r"^-(\d|\.\d)[\d.,eE+-]*$")


def attach_option_values(argv: list[str]) -> list[str]:
    """``["--look", "-30,20,3"]`` -> ``["--look=-30,20,3"]``: argparse takes a value that starts with ``-`` (a
    negative azimuth, an ``--at -0.1,0.2`` spot) for an option, so a negative number or comma list of numbers that
    follows a long option is attached to it first. Other tokens, and values after ``--``, are left as they are."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        token = argv[i]
        if token == "--":
            out.extend(argv[i:])
            break
        takes = token.startswith("--") and "=" not in token and len(token) > 2
        if takes and i + 1 < len(argv) and _NEGATIVE_NUMBERS.match(argv[i + 1]):
            out.append(f"{token}={argv[i + 1]}")
            i += 2
            continue
        out.append(token)
        i += 1
    return out


class HelpFormatter(argparse.HelpFormatter):
    """Options' help with their default appended once: not when the help already says it (``default``, ``none =``)
    and not for a default that says nothing (None, False)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        said = "%(default)" in text or "default" in text.lower() or "none =" in text.lower()
        if said or action.default in (None, False, argparse.SUPPRESS) or not action.option_strings:
            return text
        return f"{text} (default: %(default)s)"


def parse_key_values(items: list[str], what: str, example: str) -> dict[str, Any]:
    """``["a=1", "b.c=x"]`` -> ``{"a": 1, "b.c": "x"}``, each value read as a YAML scalar or list (safe YAML, as a
    config file's). OptionError naming ``what`` for an item without ``=``, an empty key or value, a key given twice
    or a value YAML cannot read; ``example`` shows the form."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key or not text.strip():
            raise OptionError(f"{what}: {item[:80]!r}: expected KEY=VALUE, e.g. {example}")
        if key in out:
            raise OptionError(f"{what}: {key[:80]} given twice")
        try:
            out[key] = load_yaml(text, f"{what}: {key[:80]}")
        except YamlError as e:
            raise OptionError(str(e)) from None
    return out
