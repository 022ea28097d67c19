"""A Ctrl-C ends a command with status 130 and one line wherever the SIGINT lands (entitynet.interrupts).

Each case injects, deterministically, a place where a real `entitynet proxy ...` run was seen to take its SIGINT
(a loop of runs with SIGINT at random moments): a string `exec` of a lazily imported `@dataclass` (the process
died by SIGINT, -2, after printing "interrupted"), a weakref callback (Python drops the KeyboardInterrupt: the
service ran on), class creation (Python 3.11 wraps it in a RuntimeError). They run as `python -m` processes
because CPython's -2 exit exists only there, and with a timeout because a lost Ctrl-C is a hang.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

#: the command `entitynet boom`, then its body: each runs inside the real `entitynet.cli.main`
MODULE = """\
import signal, sys, weakref

import trio

from entitynet import cli
from entitynet.interrupts import run_until_interrupted


def ctrl_c_in_a_weakref_callback():
    class Thing:
        pass

    thing = Thing()
    ref = weakref.ref(thing, lambda _ref: signal.raise_signal(signal.SIGINT))
    del thing  # the callback runs here; Python cannot raise from it
    return ref


def boom(_args):
{body}


cli.discover_plugins = lambda group=cli.PLUGIN_GROUP: [
    ("boom", lambda sub: sub.add_parser("boom").set_defaults(func=boom))]
sys.exit(cli.main(["boom"]))
"""

CASES = {
    "a string exec": 'exec("raise KeyboardInterrupt", {})',
    "a string eval": 'eval("signal.raise_signal(signal.SIGINT)")',
    "class creation": textwrap.dedent("""\
        class Named:
            def __set_name__(self, owner, name):
                raise KeyboardInterrupt

        class Owner:
            field = Named()"""),
    "a weakref callback while loading": "ctrl_c_in_a_weakref_callback()\nrun_until_interrupted(trio.sleep_forever)",
    "a weakref callback inside the run": textwrap.dedent("""\
        async def service():
            ctrl_c_in_a_weakref_callback()
            await trio.sleep_forever()

        run_until_interrupted(service)"""),
    "a weakref callback of a command that then finishes": "ctrl_c_in_a_weakref_callback()\nreturn 0",
}


@pytest.mark.parametrize("body", CASES.values(), ids=CASES.keys())
def test_ctrl_c_exits_130_with_one_line(tmp_path, body):
    (tmp_path / "boom_cli.py").write_text(MODULE.format(body=textwrap.indent(body, "    ")))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT)])}
    proc = subprocess.run([sys.executable, "-m", "boom_cli"], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=30)
    assert (proc.returncode, proc.stderr) == (130, "entitynet: interrupted\n")


def test_a_ctrl_c_in_the_run_cancels_it_and_raises_keyboard_interrupt_outside_trio():
    """In-process: the service's own cleanup runs (cancellation, not an exception raised at a random line)."""
    import signal

    import trio

    from entitynet.interrupts import run_until_interrupted

    cleaned = []

    async def service() -> None:
        try:
            signal.raise_signal(signal.SIGINT)
            await trio.sleep_forever()
        finally:
            cleaned.append(True)

    with pytest.raises(KeyboardInterrupt):
        run_until_interrupted(service)
    assert cleaned == [True]


def test_a_run_that_ends_by_itself_returns_its_value():
    import trio

    from entitynet.interrupts import run_until_interrupted

    async def answer(x: int) -> int:
        await trio.sleep(0)
        return 2 * x

    assert run_until_interrupted(answer, 21) == 42


def test_a_run_on_another_thread_than_the_main_one_runs_as_plain_trio():
    """Signals reach the main thread alone and trio refuses a signal receiver elsewhere: a command run from a
    worker thread (tests/proxies/test_proxy_shell.py runs `_run_shell` so) failed with RuntimeError."""
    import threading

    import trio

    from entitynet.interrupts import run_until_interrupted

    async def answer(x: int) -> int:
        await trio.sleep(0)
        return 2 * x

    got: list[object] = []
    worker = threading.Thread(target=lambda: got.append(run_until_interrupted(answer, 21)))
    worker.start()
    worker.join(30)
    assert got == [42]


def test_an_error_caused_by_an_interrupt_is_recognised_and_a_plain_one_is_not():
    from entitynet.interrupts import caused_by_interrupt

    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as ki:
            raise RuntimeError("wrapped") from ki
    except RuntimeError as exc:
        assert caused_by_interrupt(exc)
    assert not caused_by_interrupt(ValueError("plain"))
