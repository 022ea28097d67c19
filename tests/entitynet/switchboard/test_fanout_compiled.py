"""The switchboard forwards the same bytes with the compiled route and outboxes (`_fanout.pyx`, `_outbox.pyx`,
built by pip) as with the pure-Python reference (the outboxes alone: test_outbox_compiled.py).

Why: the compiled path is an optimisation, never a second behaviour; the reference stays the
fallback where no compiler was at hand. `fanout_path` runs a test once per path (the compiled one is skipped,
saying so, where it was not built; tests/conftest.py).
"""

from __future__ import annotations

from entitynet import protocol as P
from entitynet.switchboard import outbox
from tests.entitynet.switchboard_helpers import join, make, pub, recv


def _scenario() -> list[list[tuple]]:
    """Viewers on overlapping cells, entities that stay and move: what each viewer receives, in order."""
    sb = make()
    viewers = [join(sb) for _ in range(6)]
    for k, v in enumerate(viewers):
        sb.receive(v, [P.Subscribe((k % 3, 3), ())], 0.0)
        recv(sb, v)
    owner = join(sb)
    out = []
    for seq in range(1, 8):
        sb.receive(owner, [pub(1, seq, (3,)), pub(2, seq, (seq % 3,)), pub(3, seq, (1, 2))], seq * 0.1)
        if seq % 2:
            out.append([[(type(m).__name__, getattr(m, "seq", None)) for m in recv(sb, v)] for v in viewers])
    return out


def test_forwarding_is_the_same_on_both_paths(fanout_path):
    got = _scenario()
    outbox.use_compiled(False)
    want = _scenario()  # the reference
    assert got == want
    assert any(("Leave", None) in frame for step in want for frame in step)  # the scenario has LEAVEs ...
    assert sum(len(frame) for step in want for frame in step) > 30  # ... and plenty of UPDATEs
