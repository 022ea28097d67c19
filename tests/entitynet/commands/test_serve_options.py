"""`entitynet serve` options whose values parsed but broke the server: refused at start with one
`entitynet: error:` line, before anything listens (the server's start is replaced by a failure here, so an
option accepted by mistake fails the test instead of starting a server)."""

from __future__ import annotations

import pytest
import trio

from entitynet.cli import main


@pytest.fixture
def no_server(monkeypatch):
    def started(*_a, **_k):
        raise AssertionError("the server started with a broken option")

    monkeypatch.setattr(trio, "run", started)


@pytest.mark.parametrize("extra", [
    ["--grace", "inf"], ["--flush-ms", "inf"], ["--gc-full-every", "1e-9"], ["--dead-after", "1e-9"],
    ["--dead-after", "nan"], ["--dead-after", "inf"], ["--flush-min-ms", "nan"], ["--grace=-1"],
    ["--latency-budget-ms", "nan"], ["--latency-budget-ms=-1"], ["--latency-budget-ms", "1001"],
    ["--flush-fill", "0"], ["--flush-fill", "2.5"], ["--pace-ms", "nan"], ["--pace-ms=-1"], ["--pace-ms", "1001"],
    ["--nats-connect-timeout", "0"], ["--nats-connect-timeout", "nan"], ["--nats-connect-timeout", "61"],
])
def test_out_of_range_values_are_usage_errors(town_path, extra, no_server, capsys):
    with pytest.raises(SystemExit) as info:
        main(["serve", "--topology", str(town_path), "--open", "--port", "0", *extra])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.rstrip().splitlines()[-1].startswith("entitynet serve: error: argument " + extra[0].split("=")[0])


@pytest.mark.parametrize(("extra", "names"), [
    (["--flush-ms", "5", "--flush-min-ms", "8"], ["--flush-min-ms", "--flush-ms"]),
    (["--shard", "0"], ["--shard", "--cluster"]),
    (["--shards", "2", "--dead-after", "5"], ["--shards", "--dead-after", "--cluster"]),
    (["--regions", "map.json"], ["--regions", "--cluster"]),
    (["--advertise", "10.0.0.1:7400"], ["--advertise", "--cluster"]),
    (["--nats-connect-timeout", "3"], ["--nats-connect-timeout", "--cluster"]),
])
def test_options_that_would_be_ignored_or_capped_are_refused(town_path, extra, names, no_server, capsys):
    assert main(["serve", "--topology", str(town_path), "--open", "--port", "0", *extra]) == 2
    err = capsys.readouterr().err
    [line] = err.strip().splitlines()
    assert line.startswith("entitynet: error:") and all(n in line for n in names), line


def test_valid_options_reach_the_server(town_path, no_server):
    """The checks refuse only what is wrong: a valid combination gets as far as starting the server."""
    with pytest.raises(AssertionError, match="server started"):
        main(["serve", "--topology", str(town_path), "--open", "--port", "0", "--flush-ms", "5",
              "--flush-min-ms", "5", "--gc-full-every", "0", "--grace", "0", "--latency-budget-ms", "0",
              "--flush-fill", "1", "--pace-ms", "5"])


@pytest.mark.parametrize("grace", [float("inf"), float("nan"), -1.0])
def test_the_core_refuses_a_grace_that_never_ends(grace):
    """The library path too: an infinite grace kept every entity forever (the wire's grace_ms overflowed)."""
    from entitynet.switchboard import SwitchConfig

    with pytest.raises(ValueError, match="grace_s"):
        SwitchConfig(n_cells=1, digest="d", grace_s=grace)


def test_serve_with_a_damaged_token_store_stops_at_start(town_path, tmp_path, capsys):
    """A store whose data pages are damaged (the header opens) is found at start, not at the first HELLO."""
    from entitynet.auth import TokenStore
    from tests.entitynet.server.test_token_store import corrupt_index

    db = tmp_path / "users.sqlite"
    store = TokenStore(db)
    store.add_user("alice")
    store.close()
    corrupt_index(str(db))
    assert main(["serve", "--topology", str(town_path), "--users-db", str(db), "--port", "0"]) == 2
    [line] = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("entitynet: error: token store") and "damaged" in line
