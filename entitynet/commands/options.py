"""Ranges of numeric command-line options: one argparse `type=` for every number any subcommand takes.

Why one mechanism: a number that parses is not a number that works. `--grace inf` closed every HELLO,
`--flush-ms inf` delivered nothing, `--dead-after 1e-9` spun a core, `--port 65536` listened on a random port.
Each numeric option therefore names its range where it is declared (`bounded_float(lo, hi)`, `bounded_int`,
`port()`), and argparse refuses anything outside it (NaN and infinities included) at start with one line
naming the option, before anything is loaded or bound. A value with a documented special meaning (port 0 =
any free port, `--gc-full-every 0` = Python's own policy) is accepted through `special`, and the help says so.

The test tests/entitynet/commands/test_options.py walks every registered subcommand (plugins included) and
checks that each numeric option has one of these types and refuses NaN, infinity and a value below its range.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Mapping

#: the widest port range; 0 is not a port (it asks the kernel for any free one: a `special`)
PORT_MIN, PORT_MAX = 1, 65535


class Bounded:
    """An argparse type: text -> `kind` (int or float) within [lo, hi] (or (lo, hi] with `lo_open`), finite,
    or one of the `special` values (value -> what it means, for the error text)."""

    def __init__(self, kind: type, lo: float, hi: float, *, lo_open: bool = False,
                 special: Mapping[float, str] | None = None) -> None:
        if kind not in (int, float):
            raise TypeError("Bounded numbers are int or float")
        self.kind = kind
        self.lo, self.hi, self.lo_open = lo, hi, lo_open
        self.special = dict(special or {})
        self.__name__ = kind.__name__  # what argparse names in its "invalid ... value" message

    def describe(self) -> str:
        """The accepted values in words, for error messages: "a number from 0 to 3600", "an integer ..."."""
        noun = "an integer" if self.kind is int else "a number"
        lo = f"above {self.lo:g}" if self.lo_open else f"from {self.lo:g}"
        text = f"{noun} {lo} to {self.hi:g}"
        for value, meaning in sorted(self.special.items()):
            text += f", or {value:g} ({meaning})"
        return text

    def __call__(self, text: str) -> int | float:
        try:
            value = self.kind(text)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f"expected {self.describe()}, got {_shown(text)}") from None
        if value in self.special:
            return value
        low_ok = value > self.lo if self.lo_open else value >= self.lo
        finite = self.kind is int or math.isfinite(value)  # isfinite(int) overflows past ~1e308: a traceback
        if not (finite and low_ok and value <= self.hi):
            raise argparse.ArgumentTypeError(f"expected {self.describe()}, got {_shown(text)}")
        return value

    def __repr__(self) -> str:
        return f"Bounded({self.describe()})"


def _shown(text: str) -> str:
    """The refused text for an error line: a 400-digit number is shown by its start and its length."""
    return repr(text) if len(text) <= 40 else f"{text[:20]!r}... ({len(text)} characters)"


def bounded_float(lo: float, hi: float, *, lo_open: bool = False,
                  special: Mapping[float, str] | None = None) -> Bounded:
    """A finite float in [lo, hi] ((lo, hi] with `lo_open`: for durations that must be above zero)."""
    return Bounded(float, lo, hi, lo_open=lo_open, special=special)


def bounded_int(lo: int, hi: int, *, special: Mapping[float, str] | None = None) -> Bounded:
    """An integer in [lo, hi] (counts, shard numbers, seeds)."""
    return Bounded(int, lo, hi, special=special)


def positive_seconds(hi: float = 1e7) -> Bounded:
    """A duration above zero and at most `hi` seconds (default about 115 days)."""
    return bounded_float(0.0, hi, lo_open=True)


def port(*, zero: str | None = "any free port", special: Mapping[float, str] | None = None) -> Bounded:
    """A TCP port 1..65535; 0 accepted when `zero` says what it means (None: refused)."""
    extra = dict(special or {})
    if zero is not None:
        extra[0] = zero
    return bounded_int(PORT_MIN, PORT_MAX, special=extra)


#: a random seed: any non-negative integer numpy and `random` take
SEED = bounded_int(0, 2**32 - 1)

#: a length in metres of a map's geometry (street width, cell length, view distance): above 0, at most 100 km
METRES = bounded_float(0.0, 100_000.0, lo_open=True)

#: a local coordinate in metres (relative to an artifact's origin): finite and within 10,000 km
LOCAL_COORDINATE = bounded_float(-1e7, 1e7)

#: the most switchboards (regions) one cluster map may have
MAX_SHARDS = 256


def host_port(text: str) -> tuple[str, int]:
    """An argparse type: "HOST:PORT" (the last colon splits, so "::1:7400" works) with a port 1..65535; one
    parser for every option that names a server (a copy of it took port 99999)."""
    host, sep, digits = text.rpartition(":")
    if sep and host and digits.isascii() and digits.isdigit() and len(digits) <= 5:
        number = int(digits)
        if PORT_MIN <= number <= PORT_MAX:
            return host, number
    raise argparse.ArgumentTypeError(
        f"expected HOST:PORT with a port from {PORT_MIN} to {PORT_MAX}, got {_shown(text)}")


#: the latest service-day time a clock option takes: GTFS's hours run past 24 for trips after midnight
LAST_SERVICE_HOUR = 47


def time_of_day(text: str) -> float:
    """An argparse type: a service-day time "HH:MM[:SS]" (hours up to 47, GTFS's times past midnight) to seconds
    since the service day's midnight. The GTFS reader's `parse_time` does the parsing, so a clock on the command
    line means what it means in a feed; this adds the optional seconds and the ranges (a copy took 99:99:99)."""
    from topology.gtfs import GtfsError, parse_time  # here: the reader's imports only when a time is given

    parts = text.split(":")
    try:
        if len(parts) not in (2, 3):
            raise GtfsError(text)
        seconds = parse_time(text if len(parts) == 3 else text + ":00")
        if int(parts[0]) > LAST_SERVICE_HOUR or int(parts[-1] if len(parts) == 3 else 0) >= 60:
            raise GtfsError(text)
    except GtfsError:
        raise argparse.ArgumentTypeError(f"expected a service-day time HH:MM[:SS] (hours up to "
                                         f"{LAST_SERVICE_HOUR}), got {_shown(text)}") from None
    return float(seconds)
