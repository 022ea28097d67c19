"""Ctrl-C for the CLI: one place that makes an interrupt end a command with status 130 and one line, wherever
the SIGINT lands.

Why this exists (found by a loop of real `entitynet proxy ...` runs with SIGINT at random moments, see the
tests): Python's default handler raises KeyboardInterrupt in whatever code runs, and some code cannot take it.
- In a finalizer or a weakref or gc callback, Python prints "Exception ignored ... KeyboardInterrupt" and goes
  on: the Ctrl-C is lost and a service runs on (inside `trio.run`, trio raises it in any task code too).
- In a string `exec`/`eval` (every `@dataclass` a lazy import defines), CPython sets a flag that the interrupt
  went unhandled even when the CLI catches it; `python -m entitynet` then dies by SIGINT (-2), not with 130.
- In a descriptor's `__set_name__` (class creation), Python 3.11 wraps it in a RuntimeError.

So: `catching_interrupts` records interrupts Python had to drop; `run_until_interrupted` runs a long-running
command's trio loop with SIGINT taken by a signal receiver (no KeyboardInterrupt raised inside it at all) and
ends at once when a dropped interrupt came before; `forget_unhandled_flag` clears CPython's stale flag;
`caused_by_interrupt` recognises an error that an interrupt turned into. Standard library only at import: the
CLI imports this for `--help` too.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Awaitable, Callable, Iterator
from contextlib import contextmanager
from typing import TypeVar

T = TypeVar("T")

#: KeyboardInterrupts Python could not raise (printed as unraisable) since `catching_interrupts` began
_lost: list[BaseException] = []


@contextmanager
def catching_interrupts() -> Iterator[None]:
    """For the length of a command: an interrupt Python drops as unraisable is recorded silently (the command
    then ends as interrupted), not printed as a traceback and forgotten; other unraisables go on as before."""
    previous = sys.unraisablehook

    def hook(unraisable) -> None:
        if isinstance(unraisable.exc_value, KeyboardInterrupt):
            _lost.append(unraisable.exc_value)
        else:
            previous(unraisable)

    _lost.clear()
    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = previous


def take_lost_interrupt() -> bool:
    """Whether an interrupt was dropped since the last call (then forgotten: one Ctrl-C ends one thing)."""
    lost = bool(_lost)
    _lost.clear()
    return lost


def forget_unhandled_flag() -> None:
    """Clear CPython's "a KeyboardInterrupt went unhandled" flag once the CLI has handled one.

    CPython sets it when a KeyboardInterrupt leaves a string `exec`/`eval` (caught later or not) and, under
    `python -m`, ends the process by SIGINT instead of our exit status. Every string eval resets the flag when it
    starts, so a trivial one clears it; elsewhere it is harmless."""
    exec("pass", {})  # a constant string: its only effect is that reset


def caused_by_interrupt(exc: BaseException) -> bool:
    """Whether `exc` is an error an interrupt turned into (KeyboardInterrupt in its cause or context chain),
    e.g. Python 3.11's RuntimeError around a KeyboardInterrupt raised in `__set_name__`."""
    seen: set[int] = set()
    link: BaseException | None = exc
    while link is not None and id(link) not in seen:
        if isinstance(link, KeyboardInterrupt):
            return True
        seen.add(id(link))
        link = link.__cause__ or link.__context__
    return False


def run_until_interrupted(async_fn: Callable[..., Awaitable[T]], *args) -> T | None:
    """`trio.run(async_fn, *args)` for a command that runs until stopped; Ctrl-C cancels the run, then raises
    KeyboardInterrupt here, outside trio, where the CLI turns it into status 130.

    Why a signal receiver from the first moment of the run: with trio's own SIGINT handler a KeyboardInterrupt is
    raised inside task code, which can lose it (a weakref callback) and leave the service running. Before the
    receiver is open the task is KI-protected, so trio only marks an early SIGINT pending and raises it at the
    next checkpoint. An interrupt dropped before the run (during the command's loading) ends it at once.

    Off the main thread (a command run from a worker thread, as a test or an embedding program may) it is plain
    `trio.run`: Python delivers signals to the main thread alone, and a signal receiver cannot be opened there."""
    import threading

    import trio

    if threading.current_thread() is not threading.main_thread():
        return trio.run(async_fn, *args)
    interrupted = False

    async def cancel_on_sigint(signals, run: trio.CancelScope, watch: trio.CancelScope) -> None:
        nonlocal interrupted
        with watch:
            if watch.cancel_called:  # the run ended before this task first ran: the receiver is closed
                return
            async for _signum in signals:
                interrupted = True
                run.cancel()
                return

    @trio.lowlevel.enable_ki_protection
    async def guarded() -> T | None:
        nonlocal interrupted
        watch = trio.CancelScope()
        with trio.open_signal_receiver(signal.SIGINT) as signals, trio.CancelScope() as run:
            if take_lost_interrupt():
                interrupted = True
                run.cancel()
            trio.lowlevel.spawn_system_task(cancel_on_sigint, signals, run, watch)
            try:
                return await async_fn(*args)
            finally:
                watch.cancel()  # before the receiver closes under it
        return None  # cancelled by an interrupt

    result = trio.run(guarded)
    if interrupted:
        raise KeyboardInterrupt
    return result
