"""A type's body length and whether it avoids others are computed once, from its parts (the world's step reads
them several times per entity and tick), and follow the parts when a type is derived from another."""

from __future__ import annotations

import dataclasses

import pytest

from sims.engine.params import PARAMS, params


def test_length_and_avoidance_follow_the_parts():
    for name, p in PARAMS.items():
        assert p.length == float(sum(p.parts)) and p.avoids == (p.length > 0.0), name
    assert params("pedestrian").avoids is False and params("tram").length > params("car").length > 0.0
    stub = dataclasses.replace(params("car"), parts=(2.0, 3.5))  # a derived type gets its own
    assert stub.length == 5.5 and stub.avoids
    flat = dataclasses.replace(params("tram"), parts=())
    assert flat.length == 0.0 and not flat.avoids
    with pytest.raises(dataclasses.FrozenInstanceError):
        params("car").length = 1.0  # type: ignore[misc]
    with pytest.raises(ValueError, match="no entity type"):
        params("hovercraft")
