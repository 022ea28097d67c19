"""`python -m sims.bench.e2e_short` refuses bad arguments with a usage error before it starts anything."""

from __future__ import annotations

import pytest

from sims.bench.e2e_short import parse


@pytest.mark.parametrize("argv", [
    ["--systems", "nope"], ["--systems", ","], ["--seconds", "nan"], ["--seconds", "5"], ["--reps", "0"],
    ["--reps", "x"], ["--seconds", "1e9"],
])
def test_bad_arguments_are_a_usage_error(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        parse(argv)
    assert exc.value.code == 2
    assert "usage:" in capsys.readouterr().err


def test_the_defaults_are_ours_against_mosquitto():
    a = parse([])
    assert a.names == ["entitynet", "mqtt-disc"] and a.seconds == 40.0 and a.reps == 2 and not a.idle
