"""The arrows run one way: topology <- entitynet <- proxies, sims (DESIGN.md, issue 10 item 1).

Two checks. Statically, every module's imports (module level and inside functions, parsed with `ast`, so an
import that only runs in one command still counts) are matched against the forbidden directions. At run
time, in a fresh interpreter, importing the service's run-time parts must not load the build-time geometry
libraries (shapely, networkx): a phone client or a switchboard shard must not pay for them.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: package -> the packages it must never import
FORBIDDEN = {
    "topology": {"entitynet", "sims", "proxies"},
    "entitynet": {"sims", "proxies"},
    "sims": {"proxies"},  # siblings: what both need (GTFS, matching) lives in topology
}

#: run-time modules and the build-time libraries they must not load
RUNTIME_MODULES = ["entitynet.switchboard", "entitynet.server", "entitynet.protocol", "entitynet.client"]
BUILD_TIME_LIBRARIES = ["shapely", "networkx"]


def module_name(path: Path, root: Path = ROOT) -> str:
    """`topology/pvs.py` -> `topology.pvs`; `entitynet/client/__init__.py` -> `entitynet.client`."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported_modules(source: str, module: str, is_package: bool = False) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in `source`, at any depth (functions, try blocks,
    `if TYPE_CHECKING:`), relative imports resolved against `module`."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                base = base[: len(base) - node.level + (1 if is_package else 0)]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            out.append((node.lineno, name))
    return out


def violations(root: Path = ROOT, forbidden: dict[str, set[str]] = FORBIDDEN) -> list[str]:
    """`file:line: a -> b` for every import against the arrows, over every module of the packages."""
    found = []
    for package, banned in sorted(forbidden.items()):
        for path in sorted((root / package).rglob("*.py")):
            module = module_name(path, root)
            for line, name in imported_modules(path.read_text(encoding="utf-8"), module, path.name == "__init__.py"):
                top = name.split(".")[0]
                if top in banned:
                    found.append(f"{path.relative_to(root)}:{line}: {package} -> {name}")
    return found


def test_no_import_runs_against_the_arrows():
    bad = violations()
    assert not bad, "imports against topology <- entitynet <- proxies, sims:\n" + "\n".join(bad)


def test_the_checker_sees_every_kind_of_import(tmp_path):
    """The checker itself: module-level, function-level, `from` and relative imports are all caught (a
    checker that sees nothing would pass the test above on any tree)."""
    (tmp_path / "topology").mkdir()
    (tmp_path / "topology" / "__init__.py").write_text("")
    (tmp_path / "topology" / "a.py").write_text("import entitynet.cli\n")
    (tmp_path / "topology" / "b.py").write_text("def f():\n    from sims.bench import SUITES\n")
    (tmp_path / "topology" / "c.py").write_text("try:\n    import proxies\nexcept ImportError:\n    pass\n")
    (tmp_path / "topology" / "d.py").write_text("from . import raw\nfrom .raw import TRAM\nimport numpy\n")
    (tmp_path / "entitynet" / "commands").mkdir(parents=True)
    (tmp_path / "entitynet" / "__init__.py").write_text("")
    (tmp_path / "entitynet" / "commands" / "__init__.py").write_text("from sims import commands\n")
    (tmp_path / "sims").mkdir()
    (tmp_path / "sims" / "x.py").write_text("from entitynet import cli\nfrom proxies.gtfs import read_feed\n")
    (tmp_path / "proxies").mkdir()
    (tmp_path / "proxies" / "y.py").write_text("import sims, entitynet, topology\n")
    bad = violations(tmp_path)
    assert bad == [
        "entitynet/commands/__init__.py:1: entitynet -> sims",
        "sims/x.py:2: sims -> proxies.gtfs",
        "topology/a.py:1: topology -> entitynet.cli",
        "topology/b.py:2: topology -> sims.bench",
        "topology/c.py:2: topology -> proxies",
    ]


def test_relative_imports_are_resolved():
    assert imported_modules("from .raw import TRAM\n", "topology.pvs") == [(1, "topology.raw")]
    assert imported_modules("from .. import cli\n", "entitynet.commands.x") == [(1, "entitynet")]
    assert imported_modules("from . import core\n", "entitynet.switchboard", is_package=True) == [
        (1, "entitynet.switchboard")
    ]


@pytest.mark.parametrize("module", RUNTIME_MODULES)
def test_runtime_parts_load_no_build_time_geometry(module):
    code = (
        f"import json, sys; import {module}; "
        f"print(json.dumps([m for m in {BUILD_TIME_LIBRARIES!r} if m in sys.modules]))"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    loaded = json.loads(done.stdout.strip().splitlines()[-1])
    assert loaded == [], f"import {module} loads {', '.join(loaded)} (build-time only: see DESIGN.md)"


def test_the_runtime_check_would_see_a_loaded_library():
    """The subprocess probe is live: a module known to load shapely is reported."""
    code = "import json, sys; import topology.placement_index; print(json.dumps('shapely' in sys.modules))"
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert json.loads(done.stdout.strip().splitlines()[-1]) is True


def test_the_command_line_parser_loads_no_build_time_geometry():
    """Every `entitynet` process builds the whole parser (a switchboard shard's `serve` included): building it
    must not import shapely or networkx, which cost a shard about half a second of start-up."""
    code = (
        "import json, sys; import entitynet.cli as cli; cli.build_parser(); "
        f"print(json.dumps([m for m in {BUILD_TIME_LIBRARIES!r} if m in sys.modules]))"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    loaded = json.loads(done.stdout.strip().splitlines()[-1])
    assert loaded == [], f"building the CLI parser loads {', '.join(loaded)}"
