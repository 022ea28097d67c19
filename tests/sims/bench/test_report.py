"""The benchmark reports' shared helpers."""

from __future__ import annotations

import sys

import pytest

from sims.bench.report import pyplot


def test_pyplot_is_the_headless_pyplot():
    pytest.importorskip("matplotlib")
    notes: list[str] = []
    plt = pyplot(notes.append)
    assert plt is not None and hasattr(plt, "subplots") and not notes
    assert plt.get_backend().lower() == "agg"


def test_without_matplotlib_there_is_a_note_and_no_plot(monkeypatch):
    for name in [m for m in sys.modules if m == "matplotlib" or m.startswith("matplotlib.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # `import matplotlib` raises ImportError
    notes: list[str] = []
    assert pyplot(notes.append) is None
    assert notes == ["matplotlib not installed: no plot"]
