"""`sims` brings `entitynet demo` and `entitynet bench`, and other packages can add bench suites."""

from __future__ import annotations

from importlib.metadata import EntryPoint

import pytest

import sims.bench
from entitynet.cli import main


def test_bench_suites_include_installed_plugins(monkeypatch):
    extra = [EntryPoint("proxy", "proxies.bench_proxy", sims.bench.SUITE_GROUP),
             EntryPoint("dr", "somewhere.else", sims.bench.SUITE_GROUP)]
    monkeypatch.setattr(sims.bench, "entry_points", lambda group: [e for e in extra if e.group == group])
    suites = sims.bench.all_suites()
    assert suites["proxy"] == "proxies.bench_proxy"
    assert suites["dr"] == "sims.bench.dr_bench"  # a plugin does not replace a built-in suite
    assert {"topology", "pvs", "dr", "switch"} <= set(suites)


def test_bench_rejects_an_unknown_suite(capsys):
    with pytest.raises(SystemExit):
        main(["bench", "nonesuch"])
    assert "invalid choice" in capsys.readouterr().err


def test_demo_checks_its_numbers(capsys):
    with pytest.raises(SystemExit) as info:  # a usage error: refused while parsing (entitynet/commands/options.py)
        main(["demo", "--entities", "0"])
    assert info.value.code == 2 and "argument --entities: expected an integer from 1" in capsys.readouterr().err


def test_demo_refuses_a_missing_schedule_and_a_bad_start(capsys, tmp_path):
    assert main(["demo", "--gtfs", str(tmp_path / "nope.zip"), "--duration", "1"]) == 2
    assert "cannot read the feed" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["demo", "--start", "8h"])
    assert "service-day time" in capsys.readouterr().err


def test_sim_args_are_the_sim_parsers_defaults_and_refuse_unknown_names():
    """A preset of `sim` gets every option `sim` has (new ones included) and cannot name one it lacks."""
    from sims.sim_cmd import sim_args

    args = sim_args(entities=7)
    assert (args.entities, args.measure_share, args.speed, args.server) == (7, 0.25, 1.0, None)
    with pytest.raises(TypeError, match="no option 'nonesuch'"):
        sim_args(nonesuch=1)


@pytest.mark.parametrize("suite", ["e2e", "sim", "dr", "pvs"])
@pytest.mark.parametrize("artifact", ["missing", "junk"])
def test_bench_with_a_bad_topology_is_one_line(tmp_path, capsys, suite, artifact):
    """`bench SUITE --topology BAD` printed an ArtifactError traceback; the dispatcher turns it into one line."""
    path = tmp_path / "bad.enttopo"
    if artifact == "junk":
        path.write_bytes(b"\x00" * 64)
    assert main(["bench", suite, "--quick", "--topology", str(path)]) == 2
    err = capsys.readouterr().err
    assert "entitynet: error:" in err and str(path) in err and "Traceback" not in err
