"""The house rules of DESIGN.md section 2, read from the source with ast (nothing is imported).

Every import counts, the ones inside functions too: a lazy import that closes a circle is still
a circle, it only moves the failure to run time. Importing ``mamma_kit.body.lbs`` from outside
``body`` also runs ``mamma_kit/body/__init__.py``, so such an import is an edge to every package
``__init__`` on the way as well.

Rules (each test names its offenders as ``file:line  what``):
- no import cycle among mamma_kit modules (a package ``__init__`` is a module), and none among
  the top-level packages;
- no private name (``_x``, not a dunder) of one module used by another, in mamma_kit/ and in
  tests/: neither imported (``from m import _x``) nor read or patched through a name bound by an
  import (``m._x``, ``Class._x``, ``setattr(m, "_x", ...)``, ``"mamma_kit.m._x"`` strings);
- core imports nothing else from mamma_kit, and video only core;
- from outside a stage package (another stage, cli, pipeline) only the package itself or the
  submodules its ``__init__.py`` lists in ``__all__`` are imported; every stage package has an
  ``__all__`` of submodule names (core and video are shared layers: all their non-underscore
  modules are public);
- only cli/, ``__main__`` and pipeline.py import cli; only cli/ and ``__main__`` import pipeline.
"""

from __future__ import annotations

import ast
import sys
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "mamma_kit"
TESTS = ROOT / "tests"
SHARED = {"core", "video"}  # the bottom layers: every non-underscore module is public
TOP = {"cli", "pipeline", "__main__"}  # the only layers above the stages

# Known exceptions, each with the reason beside it: (file, what) as the tests print them, and
# cycles by their members. None today; an entry needs a reason a reviewer accepts.
ALLOWED_PRIVATE: set[tuple[str, str]] = set()
ALLOWED_CYCLES: list[set[str]] = []


def _is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


@dataclass(frozen=True)
class Edge:
    importer: str  # module name
    target: str  # module name (mamma_kit.* or a test module)
    names: tuple[str, ...]  # names taken from target (empty for `import x`)
    file: str  # path relative to the repo
    line: int
    implicit: bool = False  # a package __init__ run on the way to its submodule


@lru_cache(maxsize=None)
def modules() -> dict[str, Path]:
    """Module name -> file, for mamma_kit/ and the test modules (named by their file stem)."""
    out = {}
    for path in sorted((ROOT / PACKAGE).rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    for path in sorted(TESTS.glob("*.py")):
        out[path.stem] = path
    return out


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def _is_package(mod: str) -> bool:
    return modules().get(mod, Path()).name == "__init__.py"


def _resolve_from(importer: str, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    base = importer.split(".")
    if not _is_package(importer):
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _ancestors(target: str, importer: str) -> list[str]:
    """Packages whose __init__ runs when `importer` imports `target` (not the importer's own)."""
    parts = target.split(".")
    out = []
    for k in range(1, len(parts)):
        pkg = ".".join(parts[:k])
        if pkg in modules() and not (importer == pkg or importer.startswith(pkg + ".")):
            out.append(pkg)
    return out


@lru_cache(maxsize=None)
def _tree(mod: str) -> ast.Module:
    return ast.parse(modules()[mod].read_text(), filename=str(modules()[mod]))


@lru_cache(maxsize=None)
def _nodes(mod: str) -> tuple[ast.AST, ...]:
    """The import, attribute and call nodes of `mod`, at any depth (one walk per file)."""
    kinds = (ast.Import, ast.ImportFrom, ast.Attribute, ast.Call)
    return tuple(node for node in ast.walk(_tree(mod)) if isinstance(node, kinds))


@lru_cache(maxsize=None)
def edges_of(mod: str) -> tuple[Edge, ...]:
    """Every import in `mod` of a mamma_kit module or a test module, at any depth."""
    known = modules()
    file = _rel(known[mod])
    out: list[Edge] = []

    def add(target: str, names: tuple[str, ...], line: int) -> None:
        out.append(Edge(mod, target, names, file, line))
        for pkg in _ancestors(target, mod):
            out.append(Edge(mod, pkg, (), file, line, implicit=True))

    for node in _nodes(mod):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name in known:
                    add(alias.name, (), node.lineno)
        elif isinstance(node, ast.ImportFrom):
            base = _resolve_from(mod, node)
            if base not in known:
                continue
            attrs = []
            for alias in node.names:
                if f"{base}.{alias.name}" in known:  # a submodule
                    add(f"{base}.{alias.name}", (), node.lineno)
                else:
                    attrs.append(alias.name)
            if attrs or not node.names:
                add(base, tuple(attrs), node.lineno)
    return tuple(out)


def package_modules() -> list[str]:
    return [m for m in modules() if m == PACKAGE or m.startswith(PACKAGE + ".")]


def suite_modules() -> list[str]:
    return [m for m in modules() if not (m == PACKAGE or m.startswith(PACKAGE + "."))]


def _layer(mod: str) -> str | None:
    """The top-level part of mamma_kit a module belongs to (None for mamma_kit/__init__)."""
    parts = mod.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == PACKAGE else None


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components with more than one node, iteratively."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return sorted(found)


def module_cycles() -> list[str]:
    graph: dict[str, set[str]] = {m: set() for m in package_modules()}
    where: dict[tuple[str, str], Edge] = {}
    for mod in package_modules():
        for e in edges_of(mod):
            if e.target != mod and e.target in graph:
                graph[mod].add(e.target)
                where.setdefault((mod, e.target), e)
    lines = []
    for component in strongly_connected(graph):
        members = set(component)
        if members in ALLOWED_CYCLES:
            continue
        lines.append("cycle: " + ", ".join(component))
        for (a, b), e in sorted(where.items()):
            if a in members and b in members:
                how = "  (its __init__ runs first)" if e.implicit else ""
                lines.append(f"    {e.file}:{e.line}  {a} -> {b}{how}")
    return lines


def package_cycles() -> list[str]:
    graph: dict[str, set[str]] = {}
    where: dict[tuple[str, str], Edge] = {}
    for mod in package_modules():
        a = _layer(mod)
        for e in edges_of(mod):
            b = _layer(e.target)
            if a and b and a != b and not e.implicit:
                graph.setdefault(a, set()).add(b)
                graph.setdefault(b, set())
                where.setdefault((a, b), e)
    lines = []
    for component in strongly_connected(graph):
        members = set(component)
        lines.append("package cycle: " + ", ".join(component))
        for (a, b), e in sorted(where.items()):
            if a in members and b in members:
                lines.append(f"    {e.file}:{e.line}  {e.importer} -> {e.target}  (one of the {a} -> {b} imports)")
    return lines


def _import_bound_names(mod: str) -> dict[str, str]:
    """Names bound anywhere in `mod` by importing a mamma_kit or test module -> what they are."""
    known = modules()
    bound = {}
    for node in _nodes(mod):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name in known or alias.name.split(".")[0] == PACKAGE:
                    bound[alias.asname or alias.name.split(".")[0]] = alias.name
        elif isinstance(node, ast.ImportFrom):
            base = _resolve_from(mod, node)
            if base in known:
                for alias in node.names:
                    bound[alias.asname or alias.name] = f"{base}.{alias.name}"
    return bound


def _dotted(node: ast.AST) -> list[str] | None:
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        return [node.id] + parts[::-1]
    return None


def private_uses(mod: str) -> list[str]:
    """Private names of other modules that `mod` imports or reaches through an imported name."""
    file = _rel(modules()[mod])
    found = []
    for e in edges_of(mod):
        if e.implicit:
            continue
        for name in e.names:
            if _is_private(name):
                found.append(f"{e.file}:{e.line}  from {e.target} import {name}")
        last = e.target.rsplit(".", 1)[-1]
        if _is_private(last) and _layer(e.target) != _layer(mod):
            found.append(f"{e.file}:{e.line}  import of private module {e.target}")
    bound = _import_bound_names(mod)
    for node in _nodes(mod):
        if isinstance(node, ast.Attribute):
            chain = _dotted(node)
            # a chain is reported once, at its first private step (`m._a` of `m._a._b`)
            if chain and chain[0] in bound and any(_is_private(p) for p in chain[1:]):
                parent_chain = _dotted(node.value)
                if parent_chain is None or not any(_is_private(p) for p in parent_chain[1:]):
                    found.append(f"{file}:{node.lineno}  {'.'.join(chain)}  ({chain[0]} is {bound[chain[0]]})")
        elif isinstance(node, ast.Call):
            args = node.args
            func = _dotted(node.func) or []
            if (func and func[-1] in {"setattr", "getattr", "hasattr", "delattr", "object"} and len(args) >= 2
                    and isinstance(args[1], ast.Constant) and isinstance(args[1].value, str)
                    and _is_private(args[1].value)):
                owner = _dotted(args[0])
                if owner and owner[0] in bound:
                    found.append(f"{file}:{node.lineno}  {func[-1]}({'.'.join(owner)}, {args[1].value!r})")
            for arg in args[:1]:
                if (isinstance(arg, ast.Constant) and isinstance(arg.value, str)
                        and arg.value.startswith(PACKAGE + ".")
                        and any(_is_private(p) for p in arg.value.split("."))):
                    found.append(f"{file}:{node.lineno}  {func[-1] if func else 'call'}({arg.value!r})")
    return found


def public_submodules(layer: str) -> set[str] | None:
    """The submodules of mamma_kit.<layer> that other packages may import (None: all of them;
    an empty set when the package has no ``__all__``)."""
    if layer in SHARED:
        return None
    init = f"{PACKAGE}.{layer}"
    if init not in modules():
        return set()
    for node in _tree(init).body:
        target = node.targets[0] if isinstance(node, ast.Assign) and len(node.targets) == 1 else \
            node.target if isinstance(node, ast.AnnAssign) else None
        if (isinstance(target, ast.Name) and target.id == "__all__"
                and isinstance(node.value, (ast.List, ast.Tuple))):
            return {el.value for el in node.value.elts if isinstance(el, ast.Constant)}
    return set()


def has_all(layer: str) -> bool:
    init = f"{PACKAGE}.{layer}"
    return init in modules() and any(
        isinstance(t, ast.Name) and t.id == "__all__"
        for node in _tree(init).body
        for t in (node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign)
                  else []))


def stage_layers() -> list[str]:
    """Every folder of mamma_kit/ with Python files, but the shared layers and the top."""
    folders = {p.parent.name for p in (ROOT / PACKAGE).glob("*/*.py")}
    return sorted(folders - SHARED - TOP)


# ---------------------------------------------------------------------------------------------
# the tests


def _fail(title: str, lines: list[str]) -> None:
    if lines:
        raise AssertionError(f"{title}:\n" + "\n".join(lines))


def test_tarjan_finds_every_cycle_and_nothing_else():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"e", "a"}, "f": {"g"}, "g": {"f"}}
    assert strongly_connected(graph) == [["a", "b", "c"], ["f", "g"]]


def test_no_import_cycle_among_modules():
    _fail("import cycles among mamma_kit modules (function-level imports count)", module_cycles())


def test_no_import_cycle_among_packages():
    _fail("import cycles among mamma_kit's top-level packages", package_cycles())


def test_no_private_name_used_across_modules():
    lines = []
    for mod in package_modules() + suite_modules():
        file = _rel(modules()[mod])
        for line in private_uses(mod):
            what = line.split("  ", 1)[1]
            if (file, what) not in ALLOWED_PRIVATE:
                lines.append(line)
    _fail("private names (_x) of another module imported or used", lines)


def test_shared_layers_import_nothing_above_them():
    """core imports nothing else from mamma_kit; video (PyAV I/O) only core."""
    below = {"core": {"core"}, "video": {"core", "video"}}
    lines = []
    for mod in package_modules():
        a = _layer(mod)
        if a not in below:
            continue
        for e in edges_of(mod):
            b = _layer(e.target)
            if not e.implicit and b is not None and b not in below[a]:
                lines.append(f"{e.file}:{e.line}  {mod} -> {e.target}")
    _fail("a shared layer (core, video) imports a part of mamma_kit above it", lines)


def test_stage_all_lists_submodules():
    lines = []
    for layer in stage_layers():
        if not has_all(layer):
            lines.append(f"{PACKAGE}/{layer}/__init__.py  has no __all__ (an empty list: no submodule is public)")
        names = public_submodules(layer)
        for name in sorted(names or ()):
            if f"{PACKAGE}.{layer}.{name}" not in modules():
                lines.append(f"{PACKAGE}/{layer}/__init__.py  __all__ names {name!r}, which is not a submodule")
    _fail("a stage package's __all__ lists its public submodules", lines)


def test_stages_import_only_public_modules_of_other_stages():
    stages = set(stage_layers())
    lines = []
    for mod in package_modules():
        a = _layer(mod)
        for e in edges_of(mod):
            b = _layer(e.target)
            if e.implicit or b not in stages or b == a or e.target == f"{PACKAGE}.{b}":
                continue
            sub = e.target.split(".")[2]
            if sub not in public_submodules(b):
                lines.append(f"{e.file}:{e.line}  {mod} -> {e.target}  ({sub!r} is not in {PACKAGE}.{b}.__all__)")
    _fail("a stage imports another stage's internals", lines)


def test_only_the_top_imports_cli_and_pipeline():
    lines = []
    for mod in package_modules():
        a = _layer(mod)
        for e in edges_of(mod):
            b = _layer(e.target)
            if e.implicit or b == a:
                continue
            if b == "cli" and a not in TOP:
                lines.append(f"{e.file}:{e.line}  {mod} -> {e.target}")
            if b == "pipeline" and a not in {"cli", "__main__"}:
                lines.append(f"{e.file}:{e.line}  {mod} -> {e.target}")
    _fail("cli is imported only by cli/, __main__ and pipeline.py; pipeline only by cli/ and __main__", lines)


if __name__ == "__main__":  # every finding at once: python tests/test_architecture.py
    failures = 0
    for name, check in list(globals().items()):
        if name.startswith("test_") and callable(check):
            try:
                check()
            except AssertionError as e:
                failures += 1
                print(e, end="\n\n")
    print(f"{failures} rule(s) broken" if failures else "every rule holds")
    sys.exit(1 if failures else 0)
