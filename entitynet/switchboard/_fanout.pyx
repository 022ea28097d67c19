# cython: language_level=3, boundscheck=False, wraparound=False
"""The compiled fan-out: the switchboard's per-delivery loop (one dict store per viewer) in C.

Why: forwarding one PUBLISH to N viewers is N stores of the same bytes into N outboxes, and in CPython the
interpreter's loop around each store costs about as much as the store. These are the pure functions of
`entitynet.switchboard.outbox` (the reference, and the fallback where this module is not built), compiled by
Cython when pip builds the package; tests run both and compare them.
"""


def fan_out(dict states, object cids, object entity, object encoded):
    """`states[v][entity] = encoded` for every v in `cids` (all present)."""
    cdef object v
    for v in cids:
        (<dict>states[v])[entity] = encoded


def fan_out_open(dict states, object cids, object entity, object encoded):
    """As `fan_out`, skipping client ids not in `states`."""
    cdef object v, st
    for v in cids:
        st = states.get(v)
        if st is not None:
            (<dict>st)[entity] = encoded


def fan_out_to(tuple targets, object entity, object encoded):
    """`st[entity] = encoded` for every dict of `targets`."""
    cdef object st
    for st in targets:
        (<dict>st)[entity] = encoded
