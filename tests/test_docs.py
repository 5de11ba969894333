"""The commands docs/benchmarks.md names exist: each benchmarks/*.py script, and each --flag it is
shown with is one its argument parser defines (read from the script's source, nothing is run)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def script_flags(path: Path) -> set[str]:
    """Every option string passed to an ``add_argument`` call in the script."""
    flags = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "add_argument":
            flags |= {a.value for a in node.args if isinstance(a, ast.Constant) and str(a.value).startswith("-")}
    return flags


def test_benchmark_commands_in_the_docs_exist():
    text = (REPO / "docs" / "benchmarks.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)```", text, re.S)
    commands = [ln.split("#")[0] for b in blocks for ln in b.splitlines() if "benchmarks/" in ln]
    assert commands, "docs/benchmarks.md names no benchmark command"
    for cmd in commands:
        script = REPO / re.search(r"(benchmarks/\w+\.py)", cmd).group(1)
        assert script.is_file(), f"docs/benchmarks.md runs {script.name}, which does not exist"
        flags = script_flags(script)
        for flag in re.findall(r"(?<!\S)(--[\w-]+)", cmd):
            assert flag in flags, f"docs/benchmarks.md runs {script.name} with {flag}, which it does not take"
