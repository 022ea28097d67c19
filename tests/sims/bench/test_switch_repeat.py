"""The repeated-step tool (sims/bench/switch_repeat.py): runs alternate, medians are per label, variants reach
our server's command line, and a real (tiny) run against our server produces a report.

Why: the tool exists so that comparisons on a noisy machine quote medians of alternated runs; if it ran one
system's reps back to back, or lost a variant's options, its medians would compare unlike things.
"""

from __future__ import annotations

import json

import pytest

from sims.bench import switch_repeat as R


def test_runs_alternate_systems_and_variants_within_each_rep():
    plan = R.runs_plan(["entitynet", "redis"], {"a": "", "b": "--gc-full-every 0"}, 2)
    assert [(rep, label) for rep, label, _s, _x in plan] == [
        (0, "entitynet[a]"), (0, "entitynet[b]"), (0, "redis"), (1, "entitynet[a]"), (1, "entitynet[b]"), (1, "redis")]
    assert plan[1][3] == "--gc-full-every 0" and plan[2][3] == ""
    assert [label for _r, label, _s, _x in R.runs_plan(["entitynet"], {}, 1)] == ["entitynet"]


def test_medians_are_per_label_and_skip_missing_figures():
    rows = [{"label": "x", "latency_p99_ms": v, "deliveries_per_s": 1.0} for v in (50.0, 90.0, 60.0)]
    rows.append({"label": "y", "latency_p99_ms": None, "deliveries_per_s": 2.0})
    med = R.medians(rows)
    assert med["x"]["latency_p99_ms"] == 60.0 and med["x"]["runs"] == 3
    assert med["y"]["latency_p99_ms"] is None and med["y"]["deliveries_per_s"] == 2.0


@pytest.mark.parametrize("argv", [["--systems", "kafka"], ["--reps", "0"], ["--window", "nan"],
                                  ["--variant", "noequals"]])
def test_bad_arguments_are_refused(argv):
    with pytest.raises(SystemExit):
        R.main(["--topology", "missing.enttopo", *argv])


def test_a_tiny_real_run_reports_every_variant(helsinki_path, tmp_path, capsys):
    out = tmp_path / "r.json"
    assert R.main(["--topology", str(helsinki_path), "--entities", "40", "--viewers", "8", "--reps", "1",
                   "--warmup", "0.5", "--window", "1.5", "--systems", "entitynet",
                   "--variant", "default=", "--variant", "pygc=--gc-full-every 0", "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert [r["label"] for r in report["runs"]] == ["entitynet[default]", "entitynet[pygc]"]
    assert report["runs"][1]["server_args"] == "--gc-full-every 0"
    for label in ("entitynet[default]", "entitynet[pygc]"):
        assert report["medians"][label]["deliveries_per_s"] > 0
    assert "entitynet[pygc]" in json.loads(capsys.readouterr().out)
