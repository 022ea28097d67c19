"""The CLI finds the subcommands of packages above it through the `entitynet.commands` entry-point group."""

from __future__ import annotations

from importlib.metadata import EntryPoint

import pytest

from entitynet import cli


def register_hello(sub) -> None:
    """A plugin command for the tests: `entitynet hello` prints a greeting."""
    p = sub.add_parser("hello", help="say hello")
    p.set_defaults(func=lambda args: print("hello from a plugin") or 0)


def register_broken(sub) -> None:
    """A plugin whose registration fails (a bug in the plugin, not in entitynet)."""
    raise RuntimeError("plugin bug")


def _fake_entry_points(monkeypatch, *eps: tuple[str, str]) -> None:
    found = [EntryPoint(name, value, cli.PLUGIN_GROUP) for name, value in eps]
    monkeypatch.setattr(cli, "entry_points", lambda group: [e for e in found if e.group == group])


def test_installed_plugins_give_demo_and_bench():
    """The real installed metadata (pyproject.toml): sims registers demo and bench."""
    names = [name for name, _register in cli.discover_plugins()]
    assert {"demo", "bench"} <= set(names)
    commands = cli.build_parser()._subparsers._group_actions[0].choices
    assert {"topology", "serve", "users", "demo", "bench"} <= set(commands)


def test_a_plugin_command_runs(monkeypatch, capsys):
    _fake_entry_points(monkeypatch, ("hello", f"{__name__}:register_hello"))
    assert cli.main(["hello"]) == 0
    assert "hello from a plugin" in capsys.readouterr().out


def test_a_broken_plugin_warns_and_the_rest_works(monkeypatch, capsys, tmp_path):
    _fake_entry_points(monkeypatch, ("gone", "no_such_module_for_entitynet:register"),
                       ("broken", f"{__name__}:register_broken"), ("hello", f"{__name__}:register_hello"))
    assert cli.main(["hello"]) == 0
    out = capsys.readouterr()
    assert "hello from a plugin" in out.out
    assert "warning: command 'gone'" in out.err and "no_such_module_for_entitynet" in out.err
    assert "warning: command 'broken' unavailable: plugin bug" in out.err
    with pytest.raises(SystemExit) as exc:
        cli.main(["gone"])
    assert exc.value.code == 2  # argparse: no such command


def test_a_plugin_cannot_shadow_a_built_in(monkeypatch, capsys):
    _fake_entry_points(monkeypatch, ("serve", f"{__name__}:register_hello"))
    parser = cli.build_parser()
    assert "plugin command 'serve' ignored" in capsys.readouterr().err
    assert parser.parse_args(["serve", "--topology", "x.enttopo"]).port == 7400


def _raising(exc: BaseException):
    """A plugin `entitynet boom` that raises `exc`, as a command's trio nursery would."""
    def register(sub) -> None:
        def run(_args):
            raise exc

        sub.add_parser("boom").set_defaults(func=run)
    return register


@pytest.mark.parametrize("exc, status, line", [
    (KeyboardInterrupt(), 130, "entitynet: interrupted"),
    (BaseExceptionGroup("nursery", [KeyboardInterrupt()]), 130, "entitynet: interrupted"),
    (BaseExceptionGroup("outer", [BaseExceptionGroup("inner", [KeyboardInterrupt()]),
                                  type("Cancelled", (BaseException,), {})()]), 130, "entitynet: interrupted"),
    (ExceptionGroup("nursery", [cli.CommandError("bad feed")]), 2, "entitynet: error: bad feed"),
])
def test_ctrl_c_and_user_errors_inside_exception_groups_are_one_line(monkeypatch, capsys, exc, status, line):
    monkeypatch.setattr(cli, "discover_plugins", lambda group=cli.PLUGIN_GROUP: [("boom", _raising(exc))])
    assert cli.main(["boom"]) == status
    assert capsys.readouterr().err.strip() == line


def test_a_bug_inside_an_exception_group_keeps_its_traceback(monkeypatch):
    """Only interrupts and user errors are turned into one line; a bug is raised for its report."""
    group = BaseExceptionGroup("nursery", [KeyboardInterrupt(), ZeroDivisionError()])
    monkeypatch.setattr(cli, "discover_plugins", lambda group_=cli.PLUGIN_GROUP: [("boom", _raising(group))])
    with pytest.raises(BaseExceptionGroup):
        cli.main(["boom"])


def test_leaves_walks_nested_exception_groups_in_order():
    """One walker of exception groups for the CLI, `serve` and the proxies (there were three)."""
    a, b, c = ValueError("a"), KeyError("b"), OSError("c")
    group = BaseExceptionGroup("outer", [a, ExceptionGroup("inner", [b, ExceptionGroup("deep", [c])])])
    assert list(cli.leaves(group)) == [a, b, c]
    assert list(cli.leaves(a)) == [a]


def test_the_group_walkers_of_serve_and_the_proxies_are_gone():
    import entitynet.commands.serve_cmd as serve_cmd
    import proxies.commands as proxy_commands

    assert not hasattr(cli, "_leaves") and not hasattr(proxy_commands, "_find")
    assert not hasattr(serve_cmd, "_first_failure")
