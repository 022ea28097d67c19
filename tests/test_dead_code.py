"""No public function or method in the swept packages is defined and then never named anywhere (issue 10 item 7).

Why a test: dead code is read, kept in step and trusted by newcomers at the same cost as live code, and it
creeps back unseen. The check is deliberately coarse (like vulture): a definition counts as used when its name
appears anywhere in the repository's Python (as a name, an attribute or an import) or in pyproject.toml (entry
points). Tests count as users: a plain reference implementation that a written-out fast path is checked
against is kept on purpose. Read with `ast`, so it needs no optional dependency and takes well under a second.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: packages (every .py directly in them) whose public definitions must be used somewhere
SWEPT = ("entitynet/client", "proxies")

#: called by a framework, not by name from our code: `DedupPlugin.egress` is zeep's plugin hook;
#: `write_plot` is the tool that redraws docs/proxy.png from docs/proxy-bench.json (run by hand)
CALLED_FROM_OUTSIDE = {"egress", "write_plot"}

#: where names are looked for
SOURCES = ("entitynet", "topology", "sims", "proxies", "tests")


def definitions(source: str) -> list[tuple[str, int]]:
    """(name, line) of each public function or class, at module level or in a public class (dunders skipped)."""
    out: list[tuple[str, int]] = []

    def walk(node: ast.AST) -> None:
        for n in ast.iter_child_nodes(node):
            if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef) and not n.name.startswith("_"):
                out.append((n.name, n.lineno))
                if isinstance(n, ast.ClassDef):
                    walk(n)

    walk(ast.parse(source))
    return out


def references(source: str) -> set[str]:
    """Every identifier the module uses: names, attributes and imported names (definitions excluded)."""
    used: set[str] = set()
    for n in ast.walk(ast.parse(source)):
        if isinstance(n, ast.Name):
            used.add(n.id)
        elif isinstance(n, ast.Attribute):
            used.add(n.attr)
        elif isinstance(n, ast.alias):
            used.add(n.name.rsplit(".", 1)[-1])
    return used


def _python_files() -> list[Path]:
    return [p for top in SOURCES for p in sorted((ROOT / top).rglob("*.py"))]


def test_swept_packages_have_no_unused_public_definitions() -> None:
    used = set(CALLED_FROM_OUTSIDE)
    for p in _python_files():
        used |= references(p.read_text(encoding="utf-8"))
    toml = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    dead = []
    for package in SWEPT:
        for p in sorted((ROOT / package).glob("*.py")):
            for name, line in definitions(p.read_text(encoding="utf-8")):
                if name not in used and f":{name}" not in toml:
                    dead.append(f"{p.relative_to(ROOT)}:{line} {name}")
    assert not dead, f"defined but never used (remove, or say in CALLED_FROM_OUTSIDE who calls it): {dead}"


@pytest.mark.parametrize(("source", "dead"), [
    ("class A:\n    def m(self): pass\n", {"A", "m"}),
    ("class A:\n    def m(self): pass\nA().m()\n", set()),
    ("def f(): pass\ndef _g(): pass\nclass B:\n    def __init__(self): pass\n", {"f", "B"}),
])
def test_the_check_sees_methods_and_calls(source: str, dead: set[str]) -> None:
    assert {name for name, _ in definitions(source)} - references(source) == dead
