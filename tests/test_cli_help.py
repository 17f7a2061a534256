"""Every command's --help says each option's default at most once, and never "(default: None)"."""

from __future__ import annotations

import re

import pytest

from particlesplat.cli.main import COMMANDS, main

SUBCOMMANDS = {"object": ("export", "insert"), "scene": ("check",), "model": ("set",)}  # model info: no options


@pytest.mark.parametrize(
    "argv",
    [[c] for c in COMMANDS if c != "bench" and c not in SUBCOMMANDS]
    + [[c, sub] for c, subs in SUBCOMMANDS.items() for sub in subs],
)
def test_help_states_each_default_once(argv, capsys):
    with pytest.raises(SystemExit) as e:
        main([*argv, "--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    assert "(default: None)" not in " ".join(text.split())
    options = re.split(r"\n  (?=-)", text)  # one block per option
    assert len(options) > 2
    for block in options:
        said = len(re.findall(r"\bdefault\b", " ".join(block.split()), flags=re.IGNORECASE))
        assert said <= 1, block
