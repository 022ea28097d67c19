"""`entitynet serve`'s ports: out of range is refused before anything binds; a port that cannot be bound is
named (option, address, port) in one `entitynet: error:` line, without a traceback."""

from __future__ import annotations

import socket
import subprocess
import sys

import pytest

from entitynet.cli import build_parser

PORT_OPTIONS = ["--port", "--ws-port", "--metrics-port", "--http-port"]


@pytest.mark.parametrize("option", PORT_OPTIONS)
@pytest.mark.parametrize("value", ["65536", "-1", "70000", "nan", "x"])
def test_out_of_range_ports_are_refused(town_path, option, value, capsys):
    args = ["serve", "--topology", str(town_path), "--open", f"{option}={value}"]
    if option == "--http-port":
        args += ["--ws-port", "0"]
    with pytest.raises(SystemExit) as info:
        build_parser().parse_args(args)  # refused while parsing: nothing is loaded or bound
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}" in err and "65535" in err and "Traceback" not in err


@pytest.mark.parametrize("option", PORT_OPTIONS)
def test_a_port_in_use_is_named(town_path, option):
    """A real `entitynet serve` process, one of whose ports another socket already holds."""
    holder = socket.socket()
    holder.bind(("127.0.0.1", 0))
    holder.listen()
    busy = holder.getsockname()[1]
    args = {"--port": "0", "--ws-port": "0", "--metrics-port": "0", "--http-port": "0"}
    args[option] = str(busy)
    cmd = [sys.executable, "-m", "entitynet", "serve", "--topology", str(town_path), "--open"]
    for name, value in args.items():
        cmd += [name, value]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    finally:
        holder.close()
    assert proc.returncode == 2
    errors = [line for line in proc.stderr.splitlines() if line.startswith("entitynet: error:")]
    assert len(errors) == 1, proc.stderr
    assert option in errors[0] and f"127.0.0.1:{busy}" in errors[0] and "in use" in errors[0]
    assert "Traceback" not in proc.stderr
