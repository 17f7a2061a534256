"""Every JSON the program reads goes through the checked reader (``particlesplat/core/jsonfile.py``: a byte bound,
UTF-8, nesting): no bare ``json.load`` / ``json.loads`` in ``particlesplat/formats/``, and elsewhere only where a
reason is written below. The lint reads the source's syntax tree, so an alias (``from json import loads``) counts."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# module -> why its bare parse is bounded and checked another way
ALLOWED = {
    "particlesplat/core/jsonfile.py": "the checked reader itself",
    "particlesplat/training/runlog.py": "metrics.jsonl read line by line, each line at most 1 MiB; nesting caught",
    "particlesplat/bench/render.py": "the last stdout line of a benchmark child process this program started",
    "particlesplat/bench/train.py": "the last stdout line of a benchmark child process this program started",
}


def bare_json_reads(source: str) -> list[int]:
    """Line numbers of calls to json.load / json.loads (through any alias of the module or the functions)."""
    tree = ast.parse(source)
    modules, functions = set(), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            modules |= {a.asname or a.name for a in node.names if a.name == "json"}
        elif isinstance(node, ast.ImportFrom) and node.module == "json":
            functions |= {a.asname or a.name for a in node.names if a.name in ("load", "loads")}
    lines = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        if isinstance(f, ast.Attribute) and f.attr in ("load", "loads") and isinstance(f.value, ast.Name):
            if f.value.id in modules:
                lines.append(node.lineno)
        elif isinstance(f, ast.Name) and f.id in functions:
            lines.append(node.lineno)
    return lines


def test_the_lint_finds_every_spelling():
    source = "import json\nimport json as j\nfrom json import loads as L\n"
    source += "json.loads(b)\nj.load(f)\nL(x)\njson.dumps(x)\n"
    assert bare_json_reads(source) == [4, 5, 6]


def test_no_bare_json_reads_in_the_readers():
    found = []
    for folder in ("particlesplat", "viewer"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel in ALLOWED:
                continue
            found += [f"{rel}:{line}" for line in bare_json_reads(path.read_text(encoding="utf-8"))]
    assert not found, "read JSON through particlesplat.core.jsonfile (read_json, read_json_stream, parse_json): " + (
        ", ".join(found)
    )
    assert all((ROOT / rel).is_file() for rel in ALLOWED), "an allowed module is gone: drop it from ALLOWED"
