"""The `proxy` subcommand arrives through the `entitynet.commands` entry-point group (entitynet never imports
proxies: tests/test_layering.py), and its input errors are clean."""

from __future__ import annotations

from entitynet import cli


def test_the_proxy_command_is_registered_through_the_entry_point_group():
    assert any(name == "proxy" for name, _ in cli.discover_plugins())
    args = cli.build_parser().parse_args(["proxy", "replay", "--gtfs", "feed.zip", "--port", "0"])
    assert args.proxy_command == "replay" and callable(args.func)


def test_the_unreachable_notice_waits_five_seconds_unless_told(capsys):
    """`--unreachable-after` (default 5 s, as before the option) takes positive seconds only."""
    import pytest

    base = ["proxy", "gtfs-rt", "--vehicle-positions", "http://x/vp", "--server", "127.0.0.1:1", "--gtfs", "f.zip"]
    assert cli.build_parser().parse_args(base).unreachable_after == 5.0
    assert cli.build_parser().parse_args([*base, "--unreachable-after", "0.5"]).unreachable_after == 0.5
    for bad in ("0", "-1", "nan", "inf"):
        with pytest.raises(SystemExit):
            cli.build_parser().parse_args([*base, "--unreachable-after", bad])
        assert "--unreachable-after" in capsys.readouterr().err


def test_proxy_errors_are_clean(tmp_path, capsys, line_feed):
    assert cli.main(["proxy", "replay", "--gtfs", str(tmp_path / "missing.zip"), "--port", "0"]) == 2
    assert "entitynet: error: cannot read GTFS feed" in capsys.readouterr().err
    garbage = tmp_path / "garbage.enttopo"
    garbage.write_bytes(b"not an artifact")
    assert cli.main(["proxy", "replay", "--gtfs", str(line_feed), "--topology", str(garbage), "--port", "0"]) == 2
    assert "entitynet: error: cannot load topology" in capsys.readouterr().err


def test_an_unreadable_feed_is_a_clean_error(tmp_path, capsys, line_topo):
    """`proxy siri` and `proxy gtfs-rt` with a --gtfs that is no zip, or a folder: one line, no traceback."""
    from topology.artifact import save

    art = tmp_path / "line.enttopo"
    save(line_topo, art)
    garbage = tmp_path / "garbage.zip"
    garbage.write_text("not a zip\n")
    common = ["--server", "127.0.0.1:1", "--topology", str(art)]
    for feed in (garbage, tmp_path):
        assert cli.main(["proxy", "siri", "--url", "http://127.0.0.1:1/siri", *common, "--gtfs", str(feed)]) == 2
        err = capsys.readouterr().err
        assert "entitynet: error:" in err and str(feed.name) in err, err
        assert cli.main(["proxy", "gtfs-rt", "--vehicle-positions", "http://127.0.0.1:1/vp", *common,
                         "--gtfs", str(feed)]) == 2
        assert "entitynet: error:" in capsys.readouterr().err


def _interrupted(cmd: list[str], ready: str, cwd) -> tuple[int, str]:
    """Start `entitynet CMD` as a real process, wait until its stderr shows `ready`, send SIGINT (a terminal's
    Ctrl-C) and return its exit status and whole stderr."""
    import os
    import signal
    import subprocess
    import sys
    import time

    proc = subprocess.Popen([sys.executable, "-m", "entitynet", *cmd], cwd=cwd, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "ENTITYNET_CACHE": str(cwd), "PYTHONFAULTHANDLER": "1"})
    seen = []
    deadline = time.monotonic() + 60
    try:
        while ready not in (line := proc.stderr.readline()):
            assert line and time.monotonic() < deadline, "".join(seen) + (proc.stderr.read() if not line else "")
            seen.append(line)
        seen.append(line)
        time.sleep(0.5)  # inside its trio loop by now
        proc.send_signal(signal.SIGINT)
        try:
            _out, rest = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:  # a hang: SIGABRT makes faulthandler print every thread's stack
            proc.send_signal(signal.SIGABRT)
            _out, rest = proc.communicate(timeout=30)
            raise AssertionError(f"still running 30 s after Ctrl-C; its stacks:\n{''.join(seen)}{rest}") from None
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return proc.returncode, "".join(seen) + rest


def test_ctrl_c_stops_replay_and_siri_without_a_traceback(tmp_path, line_topo, line_feed):
    """Exit status 130 itself: the process died by SIGINT (-2) after printing "interrupted" in about 1 run in 25
    of `proxy siri` (a Ctrl-C in a lazily imported dataclass's string exec), and a Ctrl-C dropped in a weakref
    callback can leave a service running; tests/entitynet/test_interrupts.py injects each such place."""
    from topology.artifact import save

    art = tmp_path / "line.enttopo"
    save(line_topo, art)
    rc, err = _interrupted(["proxy", "replay", "--gtfs", str(line_feed), "--port", "0"], "replay of", tmp_path)
    assert rc == 130 and "Traceback" not in err and "entitynet: interrupted" in err, err
    rc, err = _interrupted(["proxy", "siri", "--url", "http://127.0.0.1:1/siri", "--server", "127.0.0.1:1",
                            "--topology", str(art), "--gtfs", str(line_feed)], "request(s) per poll", tmp_path)
    assert rc == 130 and "Traceback" not in err and "entitynet: interrupted" in err, err


def _gtfsrt_argv(tmp_path, line_topo, line_feed, *extra: str) -> list[str]:
    from topology.artifact import save

    art = tmp_path / "line.enttopo"
    save(line_topo, art)
    return ["proxy", "gtfs-rt", "--vehicle-positions", "http://127.0.0.1:1/vp", "--topology", str(art),
            "--gtfs", str(line_feed), *extra]


def test_a_metrics_port_in_use_is_one_line_naming_it(tmp_path, capsys, line_topo, line_feed):
    import socket

    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        taken = busy.getsockname()[1]
        argv = _gtfsrt_argv(tmp_path, line_topo, line_feed, "--server", "127.0.0.1:1", "--duration", "1",
                            "--metrics-port", str(taken))
        assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert f"entitynet: error: cannot listen on 127.0.0.1:{taken} (--metrics-port)" in err, err
    assert "in use" in err and "Traceback" not in err, err


def test_an_unreachable_server_is_reported_and_the_duration_still_ends_the_run(tmp_path, line_topo, line_feed):
    """The duration clock waited for the first connection: a proxy of an unreachable server ran forever, silently."""
    import os
    import socket
    import subprocess
    import sys
    import time

    with socket.socket() as probe:  # a port nothing listens on (bound, never listening: connections are refused)
        probe.bind(("127.0.0.1", 0))
        dead = probe.getsockname()[1]
        argv = _gtfsrt_argv(tmp_path, line_topo, line_feed, "--server", f"127.0.0.1:{dead}", "--duration", "2",
                            "--unreachable-after", "0.5")  # (the notice's default is 5 s)
        t0 = time.monotonic()
        try:
            proc = subprocess.run([sys.executable, "-m", "entitynet", *argv], cwd=tmp_path, capture_output=True,
                                  text=True, timeout=60, env={**os.environ, "ENTITYNET_CACHE": str(tmp_path)})
        except subprocess.TimeoutExpired as exc:
            raise AssertionError(f"still running after 60 s with --duration 2: {exc.stderr}") from None
    assert time.monotonic() - t0 < 40
    assert f"server 127.0.0.1:{dead} unreachable, retrying" in proc.stderr, proc.stderr
    assert proc.stderr.count("unreachable") == 1 and "Traceback" not in proc.stderr, proc.stderr
