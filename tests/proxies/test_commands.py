"""The `proxy` subcommand arrives through the `entitynet.commands` entry-point group (entitynet never imports
proxies: tests/test_layering.py), and its input errors are clean."""

from __future__ import annotations

from entitynet import cli


def test_the_proxy_command_is_registered_through_the_entry_point_group():
    assert any(name == "proxy" for name, _ in cli.discover_plugins())
    args = cli.build_parser().parse_args(["proxy", "replay", "--gtfs", "feed.zip", "--port", "0"])
    assert args.proxy_command == "replay" and callable(args.func)


def test_proxy_errors_are_clean(tmp_path, capsys):
    assert cli.main(["proxy", "replay", "--gtfs", str(tmp_path / "missing.zip"), "--port", "0"]) == 2
    assert "entitynet: error: cannot read GTFS feed" in capsys.readouterr().err
