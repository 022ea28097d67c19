"""`entitynet bench --cpus`: which CPUs a suite and what it starts run on (sims.bench.affinity)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from entitynet.cli import main
from sims.bench.affinity import CpuSpecError, allowed, parse_cpus, pinned

linux_only = pytest.mark.skipif(allowed() is None, reason="this platform sets no CPU affinity")


@pytest.mark.parametrize(("text", "want"), [
    ("all", {0, 1, 2, 3}), ("ALL", {0, 1, 2, 3}), ("one", {0}), (" 2 ", {2}), ("0,2", {0, 2}), ("1-3", {1, 2, 3}),
    ("0,2-3", {0, 2, 3}), ("3,3", {3}),
])
def test_every_spelling_names_the_cpus_it_says(text, want):
    assert parse_cpus(text, {0, 1, 2, 3}) == want


def test_one_is_the_lowest_cpu_the_process_may_use():
    assert parse_cpus("one", {5, 3, 9}) == {3}


@pytest.mark.parametrize(("text", "says"), [
    ("", "expected 'all'"), ("x", "expected 'all'"), ("1.5", "expected 'all'"), ("nan", "expected 'all'"),
    ("0,,1", "expected 'all'"), ("-1", "expected 'all'"), ("3-1", "not a range"), ("0-99999", "not a range"),
    ("7", "CPU 7 is not one"), ("0-7", "CPU 4 is not one"), ("1e9", "expected 'all'"),
])
def test_a_bad_list_is_refused_with_what_was_asked(text, says):
    with pytest.raises(CpuSpecError, match=says) as info:
        parse_cpus(text, {0, 1, 2, 3})
    assert repr(text) in str(info.value)


def test_no_cpu_allowed_is_refused():
    with pytest.raises(CpuSpecError, match="no CPU"):
        parse_cpus("all", set())


def test_a_bad_cpus_is_one_line_from_the_cli_before_the_suite_starts(capsys):
    assert main(["bench", "e2e", "--quick", "--cpus", "99999"]) == 2
    err = capsys.readouterr().err
    assert "entitynet: error: --cpus '99999'" in err and "Traceback" not in err and "[bench]" not in err


@linux_only
def test_the_pin_covers_every_thread_and_what_starts_later_and_is_undone_after():
    """Run in a child (pinning the test runner would slow the suite): a thread started before the pin is pinned
    too, a process started inside inherits the CPU, and after the block every thread may run where it could."""
    code = textwrap.dedent("""
        import os, subprocess, sys, threading
        from sims.bench.affinity import pinned
        gate, started = threading.Event(), threading.Event()
        seen = {}
        def worker():
            seen["tid"] = threading.get_native_id(); started.set(); gate.wait(30)
        t = threading.Thread(target=worker); t.start(); started.wait(30)
        before = os.sched_getaffinity(0)
        with pinned(None, "one") as placement:
            inside = (os.sched_getaffinity(0), os.sched_getaffinity(seen["tid"]), subprocess.run(
                [sys.executable, "-c", "import os; print(sorted(os.sched_getaffinity(0)))"],
                capture_output=True, text=True, check=True).stdout.strip())
        after = (os.sched_getaffinity(0), os.sched_getaffinity(seen["tid"]))
        gate.set(); t.join()
        print(sorted(before), placement, [sorted(inside[0]), sorted(inside[1]), inside[2]],
              [sorted(after[0]), sorted(after[1])], sep="|")
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True,
                         env={**os.environ, "PYTHONPATH": os.getcwd()}).stdout.strip().split("|")
    before = eval(out[0])  # noqa: S307 (our own child's repr of lists)
    lowest = [min(before)]
    assert eval(out[2]) == [lowest, lowest, str(lowest)]  # noqa: S307
    assert eval(out[3]) == [before, before]  # noqa: S307
    assert f"'cpus': {lowest}" in out[1] and f"'pinned': {len(before) > 1}" in out[1]


@linux_only
def test_all_leaves_the_process_where_it_was():
    before = os.sched_getaffinity(0)
    with pinned("all", "one") as placement:
        assert os.sched_getaffinity(0) == before
    assert placement == {"cpus_asked": "all", "cpus": sorted(before), "pinned": False}


def test_where_the_platform_cannot_pin_the_report_says_so(monkeypatch):
    import sims.bench.affinity as affinity

    monkeypatch.setattr(affinity, "allowed", lambda: None)
    with pinned("0", "one") as placement:
        assert placement["pinned"] is False and "no CPU affinity" in placement["why"]
