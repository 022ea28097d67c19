"""Every numeric option of every subcommand (plugins included) has a range, checked while parsing.

The walk finds the numeric options by what their `type=` makes of a number (so a new option cannot slip past
by using plain `float`), asserts each is an `entitynet.commands.options.Bounded`, and feeds each NaN,
infinity and a value below its range: argparse must refuse them with one line naming the option, before any
command runs (parsing only: no server starts, nothing is loaded)."""

from __future__ import annotations

import argparse
import math

import pytest

from entitynet.cli import build_parser
from entitynet.commands.options import Bounded, bounded_float, bounded_int, port


def _numeric(action: argparse.Action) -> bool:
    """True when the option's type turns a number into a number (int, float, or a custom converter)."""
    if action.type is None or isinstance(action, argparse._SubParsersAction):
        return False
    for text in ("1", "1.5", "0"):
        try:
            value = action.type(text)
        except Exception:  # a converter of something else (HH:MM, HOST:PORT) or a refused number
            continue
        if isinstance(value, int | float) and not isinstance(value, bool):
            return True
    return False


def _walk(parser: argparse.ArgumentParser, path: tuple[str, ...]):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _walk(sub, (*path, name))
        elif _numeric(action):
            yield path, parser, action


OPTIONS = list(_walk(build_parser(), ()))
IDS = [" ".join(path) + " " + (action.option_strings or [action.dest])[0] for path, _, action in OPTIONS]


def test_the_walk_finds_the_numeric_options_of_every_part():
    commands = {path[0] for path, _, _ in OPTIONS}
    assert {"serve", "cluster", "topology", "sim", "demo", "proxy"} <= commands
    assert len(OPTIONS) > 50


def _bad_values(kind: Bounded) -> list[str]:
    """NaN, both infinities, and the nearest value below and above the range that no special value takes."""
    step = 1 if kind.kind is int else 0.5
    below = kind.lo if kind.lo_open else kind.lo - step
    while below in kind.special:
        below -= step
    above = kind.hi + step
    while above in kind.special:
        above += step
    out = ["nan", "inf", "-inf", f"{below:g}", f"{above:.17g}", "9" * 400, "-" + "9" * 400]  # no OverflowError
    if kind.lo >= 0 and -1 not in kind.special:
        out.append("-1")
    return out


@pytest.mark.parametrize(("path", "parser", "action"), OPTIONS, ids=IDS)
def test_every_numeric_option_refuses_nan_infinity_and_out_of_range(path, parser, action, capsys):
    assert isinstance(action.type, Bounded), f"{' '.join(path)} {action.option_strings}: give it a range"
    name = action.option_strings[0] if action.option_strings else None
    n = action.nargs if isinstance(action.nargs, int) else 1
    for bad in _bad_values(action.type):
        argv = [f"{name}={bad}"] if name and n == 1 else ([name] if name else []) + [bad] * n
        with pytest.raises(SystemExit) as info:
            parser.parse_args(argv)
        assert info.value.code == 2
        err = capsys.readouterr().err
        errors = [line for line in err.splitlines() if ": error: " in line]
        assert len(errors) == 1 and err.rstrip().endswith(errors[0]), err
        assert f"argument {name or action.metavar or action.dest}" in errors[0] and "expected" in errors[0], err
        assert "Traceback" not in err


@pytest.mark.parametrize(("kind", "good", "bad"), [
    (bounded_float(0, 10), ["0", "10", "2.5", "1e-3"], ["-0.1", "10.01", "nan", "inf", "x", ""]),
    (bounded_float(0, 10, lo_open=True), ["1e-9", "10"], ["0", "-1"]),
    (bounded_float(1, 10, special={0: "off"}), ["0", "1", "0.0"], ["0.5", "1e-9"]),
    (bounded_int(1, 5), ["1", "5"], ["0", "6", "1.0", "nan", "9" * 400, "9" * 5000]),
    (port(), ["0", "1", "65535"], ["65536", "-1", "7400.0"]),
    (port(zero=None), ["1"], ["0"]),
    (port(special={-1: "none"}), ["-1", "0"], ["-2"]),
])
def test_bounded_types(kind, good, bad):
    for text in good:
        value = kind(text)
        assert isinstance(value, kind.kind) and math.isfinite(value)
    for text in bad:
        with pytest.raises(argparse.ArgumentTypeError, match="expected"):
            kind(text)


def test_host_port():
    from entitynet.commands.options import host_port

    assert host_port("127.0.0.1:7400") == ("127.0.0.1", 7400)
    assert host_port("::1:65535") == ("::1", 65535)
    for bad in ("127.0.0.1:99999", "h:0", "h:", ":7400", "7400", "h:74x0", "h:-1", "h:" + "9" * 400):
        with pytest.raises(argparse.ArgumentTypeError, match="HOST:PORT"):
            host_port(bad)


def test_time_of_day():
    from entitynet.commands.options import time_of_day

    assert time_of_day("08:00") == 8 * 3600.0 and time_of_day("25:10:30") == 25 * 3600 + 630.0
    for bad in ("99:99:99", "08:60", "08:00:60", "48:00", "8", "x:00", "-1:00", "08:00:00:00", ""):
        with pytest.raises(argparse.ArgumentTypeError, match="HH:MM"):
            time_of_day(bad)


def test_every_host_port_and_clock_time_option_uses_the_shared_types():
    """Two HOST:PORT parsers (one took port 99999) and two clock-time parsers (one took 99:99:99) became one each."""
    from entitynet.commands.options import host_port, time_of_day

    seen = {"--server": 0, "--start": 0}

    def walk(parser):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    walk(sub)
            elif "--server" in action.option_strings and action.metavar == "HOST:PORT":
                assert action.type is host_port
                seen["--server"] += 1
            elif "--start" in action.option_strings and action.type is not None:
                assert action.type is time_of_day, action
                seen["--start"] += 1

    walk(build_parser())
    assert seen["--server"] >= 3 and seen["--start"] >= 3, seen


def test_a_huge_number_is_shown_short_in_the_error():
    with pytest.raises(argparse.ArgumentTypeError) as info:
        bounded_int(0, 10)("9" * 400)
    assert "(400 characters)" in str(info.value) and len(str(info.value)) < 120
