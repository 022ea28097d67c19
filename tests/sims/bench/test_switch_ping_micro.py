"""`python -m sims.bench.switch_ping_micro`: bad arguments are a usage error before anything starts, and a short
run against a real `entitynet serve` completes every round trip of the lock step (with publishes too)."""

from __future__ import annotations

import json

import pytest

from sims.bench.switch_ping_micro import main


@pytest.mark.parametrize("argv", [["--rounds", "0"], ["--reps", "0"], ["--reps", "21"], ["--entities", "-1"],
                                  ["--rounds", "x"]])
def test_bad_arguments_are_a_usage_error(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert "usage:" in capsys.readouterr().err


def test_a_short_run_makes_every_round_trip(capsys):
    assert main(["--rounds", "3", "--reps", "1", "--entities", "8", "--sub-every", "2"]) == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    (run,) = out["runs"]
    assert run["round_trips"] == 3 * 34  # 4 publishers and 30 viewers, one PONG each per round
    assert run["server_us_per_round_trip"] >= 0.0 and out["entities"] == 8
