"""The demo end to end on real loopback sockets: entities publish, viewers subscribe and receive."""

from __future__ import annotations

from sims.demo import DemoConfig, run_demo


async def test_demo_runs_and_viewers_receive(helsinki, helsinki_path):
    lines: list[str] = []
    config = DemoConfig(entities=40, viewers=4, connections=2, duration=3.0, summary_every=1.0, seed=3)
    stats = await run_demo(helsinki, helsinki_path, config, lines.append)
    assert stats.published >= 40  # every entity published at least once
    assert stats.deliveries > 0
    assert stats.rejected_fixes == 0
    assert any("deliveries" in line for line in lines)
    # the demo is the sim's preset: scheduled trams and buses run among the pedestrians and cars
    assert any(" tram" in line and " bus" in line and " pedestrian" in line for line in lines)
    assert lines[-1].startswith("stopping after")
