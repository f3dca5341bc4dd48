#!/usr/bin/env python3
"""Private names that cross modules: ``from fabric.x import _name``, ``module._name`` and ``obj._attr`` reads
of an attribute no class of the reading module defines.

A leading underscore says "this module's own": another module that needs the thing asks for a public name.
Run from the repository root: ``python tools/check_seams.py [PATH ...]`` (default ``fabric tools``) prints one
line per crossing and exits 1 when there is any; ``tests/test_lint.py`` runs it. Other packages' private
names (``os._exit``) are theirs to judge; an object of a class this module defines may be read by its
private names here.
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path

__all__ = ["crossings", "main"]

PACKAGES = {"fabric"}                  # the project's own: a private name of these must not cross a module


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _defined_here(tree: ast.AST) -> set[str]:
    """Private names this module defines: attributes set on ``self``/``cls`` or any object, class and function
    names, module globals and class-level names."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) and _private(node.attr):
            names.add(node.attr)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and _private(node.name):
            names.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store) and _private(node.id):
            names.add(node.id)
        elif isinstance(node, ast.arg) and _private(node.arg):
            names.add(node.arg)
    return names


def _attributes(tree: ast.AST) -> list[tuple[ast.Attribute, str | None]]:
    """Every attribute access, with the name of the instance (or class) its enclosing method is called on
    (the first parameter of a function defined in a class body; None outside methods)."""
    found: list[tuple[ast.Attribute, str | None]] = []

    def visit(node: ast.AST, me: str | None, in_class: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                args = child.args.posonlyargs + child.args.args
                inner = args[0].arg if in_class and args else me        # a nested function keeps its method's
                visit(child, inner, False)
            elif isinstance(child, ast.ClassDef):
                visit(child, me, True)
            else:
                if isinstance(child, ast.Attribute):
                    found.append((child, me))
                visit(child, me, in_class)
    visit(tree, None, False)
    return found


def crossings(path: Path, source: str | None = None) -> list[str]:
    """``file:line: what`` for every private name of another module that ``path`` uses."""
    text = path.read_text() if source is None else source
    tree = ast.parse(text, str(path))
    own = _defined_here(tree)
    modules: set[str] = set()          # names bound to the project's modules (and what is imported from them)
    foreign: set[str] = set()          # names bound to other packages' (the standard library's): not ours to judge
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            ours = node.module.split(".")[0] in PACKAGES
            for alias in node.names:
                (modules if ours else foreign).add(alias.asname or alias.name)
                if ours and _private(alias.name):
                    out.append(f"{path}:{node.lineno}: imports {node.module}.{alias.name}")
        elif isinstance(node, ast.Import):
            for alias in node.names:
                name = (alias.asname or alias.name).split(".")[0]
                (modules if alias.name.split(".")[0] in PACKAGES else foreign).add(name)
    for node, me in _attributes(tree):
        if not _private(node.attr):
            continue
        base = node.value
        if isinstance(base, ast.Name) and base.id == me:
            continue                   # self._x, cls._x in a method of a class of this module
        if isinstance(base, ast.Call) and isinstance(base.func, ast.Name) and base.func.id == "super":
            continue
        if isinstance(base, ast.Name) and base.id in foreign:
            continue
        if node.attr in own and not (isinstance(base, ast.Name) and base.id in modules):
            continue                   # a private of a class of this module, read on another instance of it
        out.append(f"{path}:{node.lineno}: reads .{node.attr} of {ast.unparse(base)}")
    return out


def main(argv: list[str] | None = None) -> int:
    roots = [Path(p) for p in (argv if argv else ["fabric", "tools"])]
    found = []
    for root in roots:
        files = sorted(root.rglob("*.py")) if root.is_dir() else [root]
        for f in files:
            found += crossings(f)
    for line in found:
        print(line)
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
