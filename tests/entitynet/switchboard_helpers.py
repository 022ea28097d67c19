"""Drive the sans-IO switchboard in tests: connect, send messages, read what each client would receive."""

from __future__ import annotations

from entitynet import protocol as P
from entitynet.switchboard import Switchboard, SwitchConfig, outbox


def make(**kw) -> Switchboard:
    kw.setdefault("n_cells", 100)
    kw.setdefault("digest", "d")
    kw.setdefault("open_mode", True)
    kw.setdefault("seed", 1)
    authenticate = kw.pop("authenticate", None)
    return Switchboard(SwitchConfig(**kw), authenticate=authenticate)


def join(sb: Switchboard, token: str = "", now: float = 0.0) -> int:
    cid = sb.connect(now)
    sb.receive(cid, [P.Hello(P.PROTOCOL_VERSION, token, sb.config.digest)], now)
    got = recv(sb, cid)
    assert isinstance(got[0], P.Welcome), got
    return cid


def recv(sb: Switchboard, cid: int) -> list[P.Message]:
    sb.take_dirty()
    ob = sb.outbox(cid)
    if ob is None:
        return []
    return P.decode_payload(P.payload_from_encoded(ob.drain())) if len(ob) else []


def pub(entity: int, seq: int, cells, validity_ms: int = 10_000, payload: bytes = b"s") -> P.Publish:
    return P.Publish(entity, seq, tuple(cells), validity_ms, payload)


def of(msgs, t):
    return [m for m in msgs if isinstance(m, t)]


def on_both_paths(play, steps) -> tuple:
    """`play(steps, compiled)` on the compiled path and on the pure one (what each left behind), putting back
    the path that was in use."""
    was = outbox.compiled_in_use()
    try:
        return play(steps, True), play(steps, False)
    finally:
        outbox.use_compiled(was)
