"""Subcommands from other packages arrive through the `entitynet.commands` entry-point group; a broken one is a
warning, not a broken CLI; and entitynet itself never imports proxies."""

from __future__ import annotations

import ast
from importlib.metadata import EntryPoint
from pathlib import Path

import pytest

import entitynet
from entitynet import cli


def test_the_proxy_command_is_registered_through_the_entry_point_group():
    assert any(ep.name == "proxy" for ep in cli.entry_points(group=cli.PLUGIN_GROUP))
    args = cli.build_parser().parse_args(["proxy", "replay", "--gtfs", "feed.zip", "--port", "0"])
    assert args.proxy_command == "replay" and callable(args.func)


def test_a_broken_plugin_warns_and_the_rest_still_works(monkeypatch):
    broken = EntryPoint(name="broken", value="no_such_module_xyz:register", group=cli.PLUGIN_GROUP)
    monkeypatch.setattr(cli, "entry_points", lambda group: [broken])
    with pytest.warns(UserWarning, match="broken"):
        parser = cli.build_parser()
    assert parser.parse_args(["users", "list"]).command == "users"


def test_proxy_errors_are_clean(tmp_path, capsys):
    assert cli.main(["proxy", "replay", "--gtfs", str(tmp_path / "missing.zip"), "--port", "0"]) == 2
    assert "entitynet: error: cannot read GTFS feed" in capsys.readouterr().err


def test_entitynet_never_imports_proxies():
    root = Path(entitynet.__file__).parent
    for path in root.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            assert not any(n == "proxies" or n.startswith("proxies.") for n in names), path
