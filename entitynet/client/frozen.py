"""Fast constructors for the client's frozen, slotted dataclasses (models, occupations, messages).

A frozen dataclass's generated `__init__` sets every field through `object.__setattr__` looked up per field,
which costs several times a plain slotted class; the player builds a few of these at every publish. `maker`
returns a function that fills the same slots through their descriptors: the object is equal, field for field,
to the one `__init__` builds, and stays frozen. It skips `__post_init__` (callers that need one do its work).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import fields
from typing import Any


def maker(cls: type) -> Callable[..., Any]:
    """A constructor taking every field of `cls` positionally, in declaration order (no defaults)."""
    names = [f.name for f in fields(cls)]
    ns: dict[str, Any] = {"_new": object.__new__, "_cls": cls}
    for n in names:
        ns[f"_set_{n}"] = cls.__dict__[n].__set__
    body = "".join(f"    _set_{n}(o, {n})\n" for n in names)
    exec(f"def make({', '.join(names)}):\n    o = _new(_cls)\n{body}    return o\n", ns)  # noqa: S102
    make = ns["make"]
    make.__doc__ = f"{cls.__name__}(...) without the dataclass __init__ (see `entitynet.client.frozen`)."
    return make
