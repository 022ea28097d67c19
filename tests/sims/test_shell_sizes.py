"""The shell's per-tick cache of arrivals' encoded sizes (issue 11, more entities in real time): the viewers'
byte counts stay the encoded sizes, each distinct message encoded once per tick; and `--measure-share`."""

from __future__ import annotations

import pytest

from entitynet import protocol as P
from entitynet.cli import main
from sims.engine.sim import Sim, SimConfig
from sims.shell import Shell, ShellConfig
from tests.sims.engine.test_routes import grid


def _shell() -> Shell:
    sim = Sim(grid(), SimConfig(entities=2, viewers=2, subscribe="radius", radius=300.0, transit=False, start=0.0))
    return Shell(sim, ShellConfig(duration=1.0, keys=False), lambda m: None)


def test_an_arrival_is_counted_at_its_encoded_size_and_encoded_once(monkeypatch):
    shell = _shell()
    a = P.Update(7, 3, (1, 2, 9), 4500, b"\x93\x01\x02\x03", None)
    same = P.Update(7, 3, (1, 2, 9), 4500, b"\x93\x01\x02" + bytes([3]), None)  # another viewer's copy
    other = P.Update(7, 4, (1, 2), 4500, b"\x93\x01\x02\x04\x05", "bob")
    leave = P.Leave(7)
    calls = []
    real = P.encode_message
    monkeypatch.setattr(P, "encode_message", lambda m: calls.append(m) or real(m))
    got = [shell.viewer_fleet.size(m) for m in (a, same, other, leave, leave)]
    assert got == [len(real(m)) for m in (a, same, other, leave, leave)]
    assert calls == [a, other, leave]
    deliveries = []
    shell.sim.viewers[1].receive = lambda m, now, size=0: deliveries.append((m, size))
    shell.viewer_fleet.on_message(1)(a)
    assert deliveries == [(a, len(real(a)))]


def test_cli_refuses_a_bad_measure_share(capsys):
    with pytest.raises(SystemExit) as info:  # a usage error: refused while parsing (entitynet/commands/options.py)
        main(["sim", "--measure-share", "0", "--duration", "1"])
    assert info.value.code == 2 and "argument --measure-share" in capsys.readouterr().err


async def test_viewers_share_one_decoder_and_count_each_arrival_at_its_encoded_size(helsinki, helsinki_path):
    import trio

    sim = Sim(helsinki, SimConfig(entities=30, viewers=4, connections=2, tick_hz=4.0, transit=False, seed=4,
                                  subscribe="radius"))
    shell = Shell(sim, ShellConfig(duration=2.0, speed=2.0, summary_every=1e9, artifact=helsinki_path, keys=False),
                  lambda m: None)
    got: list[tuple[list[P.Message], int]] = []  # what reached the viewers: messages, and the bytes counted

    def recording(v):
        one, frame = v.receive, v.receive_frame

        def receive(m, now, size=0):
            got.append(([m], size))
            one(m, now, size)

        def receive_frame(msgs, now, size, decoded=False):
            got.append((list(msgs), size))
            frame(msgs, now, size, decoded)

        v.receive, v.receive_frame = receive, receive_frame

    for v in sim.viewers:
        recording(v)
    with trio.fail_after(60):
        rep = await shell.run()
    arrivals = [(ms, size) for ms, size in got if all(isinstance(m, P.Update | P.Leave) for m in ms)]
    assert sum(len(ms) for ms, _ in arrivals) > 50 and rep["viewers"]["bytes"] == sum(s for _, s in arrivals)
    assert all(size == sum(len(P.encode_message(m)) for m in ms) for ms, size in arrivals)
    # the viewers' frames carried the same messages: decoded once, the same object handed to each viewer
    assert shell.viewer_fleet.messages.hits > shell.viewer_fleet.messages.misses > 0
