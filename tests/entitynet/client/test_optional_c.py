"""The one rule for the client's optional compiled twins (entitynet/client/optional_c.py): the module where it
was built, None where it was not or where ENTITYNET_PURE_PYTHON asks for the pure references."""

from __future__ import annotations

import importlib
import importlib.util
import os

import pytest

from entitynet.client import coverage, ghost_table, lateral, occupation, payload
from entitynet.client.optional_c import compiled

PURE_AT_IMPORT = bool(os.environ.get("ENTITYNET_PURE_PYTHON"))  # how this process imported the client
BUILT = importlib.util.find_spec("entitynet.client._payload") is not None


def test_a_module_that_was_not_built_is_none():
    assert compiled("_no_such_twin") is None


def test_the_pure_references_when_asked_for(monkeypatch):
    monkeypatch.setenv("ENTITYNET_PURE_PYTHON", "1")
    assert compiled("_payload") is None


@pytest.mark.skipif(not BUILT, reason="the compiled client was not built")
def test_a_built_module_is_loaded(monkeypatch):
    monkeypatch.delenv("ENTITYNET_PURE_PYTHON", raising=False)
    assert compiled("_payload") is importlib.import_module("entitynet.client._payload")


@pytest.mark.skipif(not BUILT or PURE_AT_IMPORT, reason="the compiled client was not built, or not selected")
def test_the_client_modules_took_their_twins():
    for module, twin in ((coverage, "_cover"), (occupation, "_occupy"), (payload, "_payload"),
                         (ghost_table, "_ghost_queue"), (lateral, "_lateral"), (lateral, "_waytable")):
        attr = "_WAYTABLE" if twin == "_waytable" else "_COMPILED"
        assert getattr(module, attr) is importlib.import_module(f"entitynet.client.{twin}"), module.__name__
