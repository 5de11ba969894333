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


def test_the_command_reference_is_generated_from_the_current_commands():
    from mamma_kit.cli.reference import command_reference

    current = (REPO / "docs" / "commands.md").read_text()
    assert current == command_reference(), (
        "docs/commands.md is older than the commands: run `python -m mamma_kit.cli.reference docs/commands.md`")


def command_options() -> dict[str, set[str]]:
    """Every command path ("fit", "body export") and the option strings it takes."""
    import typer

    from mamma_kit.cli.app import app
    from mamma_kit.cli.pipeline import VIDEO_LIST_OPTIONS

    out: dict[str, set[str]] = {}

    def walk(cmd, path):
        out[path] = {o for p in cmd.params for o in (*p.opts, *p.secondary_opts)}
        for name, sub in getattr(cmd, "commands", {}).items():
            walk(sub, f"{path} {name}".strip())

    walk(typer.main.get_command(app), "")
    out["init"] |= set(VIDEO_LIST_OPTIONS)
    return out


def test_the_commands_the_docs_show_take_the_options_they_are_shown_with():
    options = command_options()
    globals_ = options[""]
    docs = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
    checked = 0
    for doc in docs:
        if doc.name == "commands.md":
            continue
        for line in doc.read_text().splitlines():
            for m in re.finditer(r"mamma-kit((?: [a-z][\w-]*)+)([^`|#\n]*)", line):
                words = m.group(1).split()
                path = next((" ".join(words[:n]) for n in (2, 1) if " ".join(words[:n]) in options), None)
                if path is None:
                    continue  # prose ("mamma-kit is ..."), not a command
                for flag in re.findall(r"(?<![\w-])(--[a-z][\w-]*)", m.group(2)):
                    assert flag in options[path] | globals_, f"{doc.name}: `mamma-kit {path}` has no {flag}: {line.strip()}"
                    checked += 1
    assert checked > 50, checked


def test_help_texts_lose_nothing_to_rich_markup():
    """--help renders help texts as rich markup: an unescaped "[settings.track]" is taken for a
    style tag and silently dropped. Every help text must render to what it says."""
    import typer
    from rich.text import Text

    from mamma_kit.cli.app import app

    lost = []

    def walk(cmd, path):
        texts = [cmd.help or ""] + [getattr(p, "help", None) or "" for p in cmd.params]
        for raw in texts:
            if Text.from_markup(raw).plain != raw.replace("\\[", "["):
                lost.append(f"{path or 'mamma-kit'}: {raw[:80]}")
        for name, sub in getattr(cmd, "commands", {}).items():
            walk(sub, f"{path} {name}".strip())

    walk(typer.main.get_command(app), "")
    assert not lost, "help texts that rich markup cuts (escape [ as \\[):\n" + "\n".join(lost)
