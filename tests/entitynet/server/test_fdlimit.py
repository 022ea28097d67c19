"""The descriptor guard (entitynet/server/fdlimit.py, accept.py) against a server in a subprocess whose soft
RLIMIT_NOFILE is lowered, so that the test process keeps its own limit. Real loopback sockets."""

from __future__ import annotations

import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from entitynet import protocol as P
from tests.entitynet.server_helpers import DIGEST

resource = pytest.importorskip("resource")

SERVER = """
import logging, resource, sys, trio
soft, raise_nofile, reserve = int(sys.argv[1]), sys.argv[2] == "1", int(sys.argv[3])
resource.setrlimit(resource.RLIMIT_NOFILE, (soft, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))
logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s %(message)s")
from entitynet.server import ServerConfig, serve_until_signal
trio.run(serve_until_signal, ServerConfig(port=0, digest=sys.argv[4], n_cells=10, open_mode=True,
                                          raise_nofile=raise_nofile, fd_reserve=reserve))
"""
ROOT = Path(__file__).resolve().parents[3]


class Subserver:
    """`entitynet.server` in a child process with the given soft descriptor limit; its log in a file."""

    def __init__(self, tmp_path: Path, soft: int, raise_nofile: bool, reserve: int) -> None:
        self.log_path = tmp_path / "server.log"
        self._log = open(self.log_path, "w")
        self.proc = subprocess.Popen(
            [sys.executable, "-c", SERVER, str(soft), "1" if raise_nofile else "0", str(reserve), DIGEST],
            stdout=self._log, stderr=subprocess.STDOUT, cwd=ROOT)
        deadline = time.monotonic() + 20
        while (m := re.search(r"listening .*\bport=(\d+).*\n", self.log())) is None:
            assert self.proc.poll() is None, self.log()
            assert time.monotonic() < deadline, "server did not start: " + self.log()
            time.sleep(0.05)
        self.port = int(m.group(1))
        self.listening = m.group(0)

    def log(self) -> str:
        return self.log_path.read_text()

    def close(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)
        self._log.close()


def _hello(port: int, timeout: float = 3.0) -> tuple[socket.socket, P.Message | None]:
    """Connect, send HELLO, return the socket and the first message (None when closed without one)."""
    s = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    s.sendall(P.encode_frame([P.Hello(P.PROTOCOL_VERSION, "", DIGEST)]))
    dec = P.FrameDecoder(P.CodecLimits())
    while (msgs := dec.next_messages()) is None:
        data = s.recv(65_536)
        if not data:
            return s, None
        dec.receive_data(data)
    return s, msgs[0]


def _welcomed_within(port: int, seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    for _ in range(100):
        s, first = _hello(port)
        s.close()
        if isinstance(first, P.Welcome):
            return True
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return False


@pytest.fixture
def subserver(tmp_path):
    started: list[Subserver] = []

    def start(**kw) -> Subserver:
        started.append(Subserver(tmp_path, **kw))
        return started[-1]

    yield start
    for s in started:
        s.close()


def test_soft_limit_is_raised_to_the_hard_limit_and_said(subserver):
    hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
    if hard != resource.RLIM_INFINITY and hard <= 100:
        pytest.skip("hard descriptor limit too low to lower the soft one under it")
    expected = hard if hard != resource.RLIM_INFINITY else int(Path("/proc/sys/fs/nr_open").read_text())
    server = subserver(soft=100, raise_nofile=True, reserve=64)
    assert f"descriptor limit raised soft_before=100 soft={expected}" in server.log()
    assert f"fd_limit={expected}" in server.listening


def test_refuses_with_server_full_before_running_out_of_descriptors(subserver):
    server = subserver(soft=64, raise_nofile=False, reserve=16)
    socks, kinds = [], []
    try:
        for _ in range(60):  # more clients than the limit allows: each is answered, none is left hanging
            s, first = _hello(server.port)
            socks.append(s)
            kinds.append(type(first).__name__ if not isinstance(first, P.Error) else P.ErrorCode(first.code).name)
        welcomed, full = kinds.count("Welcome"), kinds.count("SERVER_FULL")
        assert welcomed + full == 60, kinds
        assert 10 <= welcomed <= 64 - 16 and full >= 60 - (64 - 16), kinds
        assert kinds == ["Welcome"] * welcomed + ["SERVER_FULL"] * full  # refused only once near the limit
    finally:
        for s in socks:
            s.close()
    assert _welcomed_within(server.port, 5.0)  # descriptors given back: clients are admitted again
    log = server.log()
    assert "connection refused" in log and "descriptor limit (64) nearly reached" in log
    assert "Traceback" not in log and "EMFILE" not in log


def test_emfile_in_accept_is_one_line_without_traceback(subserver):
    # the guard switched off (a negative reserve), so that accept itself runs out of descriptors
    server = subserver(soft=48, raise_nofile=False, reserve=-1000)
    socks = []
    try:
        for _ in range(60):
            s = socket.create_connection(("127.0.0.1", server.port), timeout=3)
            s.sendall(P.encode_frame([P.Hello(P.PROTOCOL_VERSION, "", DIGEST)]))
            socks.append(s)
        deadline = time.monotonic() + 10
        while "accept failed" not in server.log():
            assert time.monotonic() < deadline, server.log()
            time.sleep(0.05)
    finally:
        for s in socks:
            s.close()
    assert _welcomed_within(server.port, 5.0)  # the backlog drains and the server recovers
    log = server.log()
    assert re.search(r"WARNING entitynet.server accept failed; retrying errno=EMFILE", log), log
    assert "Traceback" not in log
    assert log.count("accept failed") <= 12  # throttled: at most one line a second
