"""The PVS options of `entitynet topology build` (glue that lives in entitynet, not in topology)."""

from __future__ import annotations

import argparse

import pytest

from entitynet.commands.pvs_cmd import add_pvs_arguments, pvs_config_from_args
from topology.pvs import PvsConfig


def test_cli_options():
    p = argparse.ArgumentParser()
    add_pvs_arguments(p)
    cfg = pvs_config_from_args(p.parse_args(["--pvs-quality", "fast", "--view-distance", "300"]))
    assert cfg.quality == "fast" and cfg.view_distance == 300.0 and cfg.samples == 2
    assert pvs_config_from_args(p.parse_args([])) == PvsConfig.from_quality("default") == PvsConfig()
    with pytest.raises(SystemExit):
        p.parse_args(["--view-cell-size", "-3"])
