"""The outbox is the boundary between the core and the shell; time and identity come in from outside.

Why: the core used to write into `outbox.states` directly and the shell inlined `Outbox.drain` and read core
tables (`sb.clients`), so neither side could change its data structures alone; the handshake timeout and the
expiry polling lived in the shell; the core asked the token store itself. These tests pin the new contract.
"""

from __future__ import annotations

import ast
from pathlib import Path

import entitynet.server
import entitynet.switchboard
from entitynet import protocol as P
from entitynet.protocol import ErrorCode
from entitynet.switchboard import Switchboard, SwitchConfig
from tests.entitynet.switchboard_helpers import join, make, pub, recv

_OUTBOX_INSIDES = {"states", "control", "overflow", "_states", "_control", "_overflow", "_close_after"}


def _is_core(node: ast.expr) -> bool:
    """`sb` or `<anything>.sb`: how the shell names its Switchboard."""
    return (isinstance(node, ast.Name) and node.id == "sb") or (isinstance(node, ast.Attribute) and node.attr == "sb")


def _reaches(path: Path, names: set[str], on_core: bool = False) -> list[str]:
    """`obj.<name>` attribute accesses in a module (and assignments to `.close_after`); with `on_core`, only
    those whose `obj` is the switchboard."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Attribute) and (not on_core or _is_core(node.value)):
            if node.attr in names or (node.attr == "close_after" and isinstance(node.ctx, ast.Store)):
                found.append(f"{path.name}:{node.lineno} .{node.attr}")
    return found


def test_no_module_but_the_outbox_touches_outbox_insides():
    sw = Path(entitynet.switchboard.__file__).parent
    srv = Path(entitynet.server.__file__).parent
    offenders = []
    for path in sorted([*sw.glob("*.py"), *srv.glob("*.py")]):
        if path.name != "outbox.py":
            offenders += _reaches(path, _OUTBOX_INSIDES)
    assert offenders == []


def test_the_shell_reads_no_core_tables():
    srv = Path(entitynet.server.__file__).parent
    offenders = []
    for path in sorted(srv.glob("*.py")):
        offenders += _reaches(path, {"clients", "entities", "subscribers", "occupants", "timers", "hello_timers",
                                     "outboxes", "_dirty", "_states"}, on_core=True)
    assert offenders == []


def test_the_handshake_deadline_lives_in_the_core():
    sb = make(handshake_timeout_s=2.0)
    quick = join(sb, now=0.5)
    silent = sb.connect(1.0)
    assert sb.next_deadline() == 3.0  # the silent one's; the quick one's was cancelled by its HELLO
    sb.expire(2.9)
    assert recv(sb, silent) == [] and not sb.outbox(silent).close_after
    sb.expire(3.0)
    (err,) = recv(sb, silent)
    assert err.code == ErrorCode.HANDSHAKE_REQUIRED and "2 s" in err.text and sb.outbox(silent).close_after
    assert sb.next_deadline() is None and recv(sb, quick) == []


def test_next_deadline_is_the_earliest_of_expiries_and_handshakes():
    sb = make(handshake_timeout_s=10.0, grace_s=1.0)
    a = join(sb, now=0.0)
    sb.receive(a, [pub(1, 1, (1,), validity_ms=2000)], 0.0)
    assert sb.next_deadline() == 3.0
    sb.connect(1.0)
    assert sb.next_deadline() == 3.0
    sb.expire(3.0)
    assert sb.next_deadline() == 11.0


def test_authentication_is_an_injected_callable():
    asked: list[str] = []

    def authenticate(token: str) -> str | None:
        asked.append(token)
        return {"t1": "alice"}.get(token)

    sb = Switchboard(SwitchConfig(n_cells=10, digest="d", seed=1), authenticate=authenticate)
    ok, bad = sb.connect(0.0, peer="a"), sb.connect(0.0, peer="b")
    sb.receive(ok, [P.Hello(P.PROTOCOL_VERSION, "t1", "d")], 0.0)
    sb.receive(bad, [P.Hello(P.PROTOCOL_VERSION, "nope", "d")], 0.0)
    assert isinstance(recv(sb, ok)[0], P.Welcome) and sb.user_of(ok) == "alice"
    assert recv(sb, bad)[0].code == ErrorCode.AUTH_FAILED
    assert asked == ["t1", "nope"]
    assert "authenticate" not in SwitchConfig.__dataclass_fields__  # configuration is data, not a resolver
