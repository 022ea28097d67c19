"""The UPDATE and LEAVE wire layouts exist once: what the switchboard core forwards is what the codec defines.

Why: the core pre-encodes every forwarded UPDATE (once per publish, the same bytes for every viewer) for speed.
It used to write the layout itself with msgpack, next to the codec's own encoder, so a change to one could
silently make the switch send bytes the protocol does not describe.
"""

from __future__ import annotations

import ast
from pathlib import Path

import entitynet.switchboard
from entitynet import protocol as P
from tests.entitynet.switchboard_helpers import join, make, pub


def _drained(sb, cid) -> list[bytes]:
    sb.take_dirty()
    return sb.outbox(cid).drain()


def test_core_update_bytes_are_the_codec_update():
    sb = make()
    owner, viewer = join(sb), join(sb)
    sb.receive(viewer, [P.Subscribe((1, 2, 3), ())], 0)
    sb.receive(owner, [pub(7, 4, (2, 3), validity_ms=1500, payload=b"\x00opaque\xff")], 0)
    (enc,) = _drained(sb, viewer)
    (upd,) = P.decode_payload(P.payload_from_encoded([enc]))
    assert upd == P.Update(upd.entity, 4, (2, 3), 1500, b"\x00opaque\xff", None)
    assert enc == P.encode_message(upd) == P.encode_update(upd.entity, 4, (2, 3), 1500, b"\x00opaque\xff")
    sb.receive(owner, [P.Unpublish(7)], 0)
    (enc,) = _drained(sb, viewer)
    assert enc == P.encode_message(P.Leave(upd.entity)) == P.encode_leave(upd.entity)


def test_core_update_with_identity_is_the_codec_update():
    sb = make()
    owner, viewer = join(sb, "alice"), join(sb, "bob")
    sb.receive(owner, [P.Privacy("alice", ("bob",))], 0)
    sb.receive(viewer, [P.Privacy("bob", None), P.Subscribe((5,), ())], 0)
    sb.receive(owner, [pub(1, 1, (5,))], 0)
    (enc,) = _drained(sb, viewer)
    (upd,) = P.decode_payload(P.payload_from_encoded([enc]))
    assert upd.identity == "alice"
    assert enc == P.encode_message(upd)


def test_query_result_is_built_from_the_same_update_bytes():
    upd = P.Update(2**40, 3, (1, 9), 1000, b"x", "carol")
    enc = P.encode_message(P.QueryResult(5, (upd,)))
    assert enc == P.encode_query_result(5, [P.encode_update(*[getattr(upd, f) for f in upd.__slots__])])
    assert P.decode_payload(P.payload_from_encoded([enc])) == [P.QueryResult(5, (upd,))]


def test_no_switchboard_module_writes_wire_layouts_itself():
    """The core encodes through entitynet.protocol only: no module of the switchboard imports msgpack."""
    offenders = []
    for path in sorted(Path(entitynet.switchboard.__file__).parent.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            if any(n.split(".")[0] == "msgpack" for n in names):
                offenders.append(path.name)
    assert offenders == []
