# cython: language_level=3, boundscheck=True, wraparound=True
# distutils: extra_compile_args = -ffp-contract=off
"""`Coverage.occupation` for a network model on a way, compiled (entitynet/client/coverage.py; the pure method
is the reference, used where pip did not build this module or with ENTITYNET_PURE_PYTHON=1).

Why: the publish's cover was three `Occupation`s, two tuples of cells and a dozen small Python calls around the
compiled `occupy` and the lateral cover (issue 22: the glue between compiled pieces was the cost). Here `occupy`
is called at C level for its fields (`_occupy.occupy_parts`), the standing walker's way behind and the lateral
cells are added to that one list, the validity is cut to the wire's milliseconds (`wire_validity`) in C, and
one `Occupation` is built at the end. The parts that are rare (the way behind a standing walker, a route's
known stretch and look-ahead) and the lateral queries (`NearIndex`, compiled there) are the Python calls the
reference makes, so each keeps one home.

Exactness: the same IEEE operations in the reference's order (`-ffp-contract=off`); `min` and `max` as Python's
builtins choose (the first argument unless the second is strictly smaller / larger); a validity that `int()`
could not take in C (not finite, or beyond 1e12 s) goes to the pure `wire_validity`, which raises or answers as
before. tests/entitynet/client/test_cover_compiled.py holds the two equal on the map's publishes and hostile
input."""

from libc.math cimport fabs

from entitynet.client._occupy cimport occupy_parts

from entitynet.client import kinematics as _kin
from entitynet.client import occupation as _occ
from entitynet.client.lateral import near_index

#: `coverage.MAX_PUBLISH_CELLS`, `LATERAL_AHEAD_TIME` and `LATERAL_AHEAD_MIN` (coverage.py imports this module, so
#: they are written here too, and a test holds them equal: `constants()`); the others read from their homes
cdef Py_ssize_t MAX_CELLS = 64
cdef double AHEAD_TIME = 12.0
cdef double AHEAD_MIN = 10.0
cdef double A_EPS = _kin.A_EPS
cdef double LOOKAHEAD = _occ.LOOKAHEAD


def constants():
    """The constants coverage.py also defines, for the test that holds them equal (one meaning each)."""
    return {"MAX_PUBLISH_CELLS": MAX_CELLS, "LATERAL_AHEAD_TIME": AHEAD_TIME, "LATERAL_AHEAD_MIN": AHEAD_MIN}


cdef inline double _min(double a, double b):
    """Python's min(a, b) of two floats."""
    return b if b < a else a


cdef inline double _max(double a, double b):
    """Python's max(a, b) of two floats."""
    return b if b > a else a


cdef double _advance_d(double v, double a, double vmax, double dt):
    """`kinematics.advance(v, a, vmax, dt)[0]` (the distance), the same operations in the same order."""
    cdef double t_stop, t_cap
    if dt <= 0.0:
        return 0.0
    a = 0.0 if (-A_EPS < a and a < A_EPS) else a
    if a < 0.0:
        t_stop = v / -a
        if dt >= t_stop:
            return v * t_stop + 0.5 * a * t_stop * t_stop
        return v * dt + 0.5 * a * dt * dt
    if a > 0.0 and v < vmax:
        t_cap = (vmax - v) / a
        if dt <= t_cap:
            return v * dt + 0.5 * a * dt * dt
        return v * t_cap + 0.5 * a * t_cap * t_cap + vmax * (dt - t_cap)
    return v * dt


cdef object _wire(double validity):
    """`occupation.wire_validity`: whole milliseconds that decode back to themselves."""
    cdef long long ms
    cdef double q
    if not fabs(validity) < 1e12:  # NaN, infinities, huge: the pure function (int() raises or is exact there)
        q = _occ.wire_validity(validity)
        return validity if q == validity else q
    ms = <long long>(validity * 1000.0)  # int(): truncation toward zero
    q = <double>ms / 1000.0
    while ms > 0 and <long long>(q * 1000.0) < ms:
        ms -= 1
        q = <double>ms / 1000.0
    return validity if q == validity else q  # (the reference keeps the occupation, -0.0 included, when equal)


cdef void _add(list cells, object extra) except *:
    """Append `extra`'s cells not yet listed, while the list has fewer than MAX_CELLS."""
    for c in extra:
        if c not in cells and len(cells) < MAX_CELLS:
            cells.append(c)


def network_occupation(cov, ghost, trk, lateral):
    """`Coverage.occupation(t, ghost, trk, estimate_xy, lateral)` for a `NetworkModel` ghost with the tracker
    on a way (`cov` the Coverage): the wired `Occupation`."""
    et = cov.etype
    path = ghost.path
    cdef double s = ghost.s0, v = ghost.v, a = ghost.a, vmax = et.vmax, margin = cov.margin
    cdef bint has_route = cov.has_route
    cdef double known = cov.route.known_until(path, s)
    look = cov.lookahead
    if look is None:
        look = _occ.lookahead_for(v, a, vmax) if has_route else LOOKAHEAD
    cdef double mv = cov.max_validity, hb = cov.heartbeat
    networks = et.networks
    cdef tuple o = occupy_parts(path, s, et.length, v, a, vmax, networks, known, margin, look, None, _min(mv, hb),
                                0.5, path.edges[-1] == trk.dead_end, ghost.time_to, 40.0)
    cdef list cells = o[0]
    cdef double validity = o[1], cover_end = o[5], back_len = 0.0, ahead, lat, d
    cdef bint behind = False
    if v == 0.0 and not has_route and cov.body == 0.0:
        # a walker standing still may turn and leave the other way (`Coverage._behind`)
        back = cov._behind(path, s, cov.lateral, networks)
        _add(cells, back.cells)
        validity = _min(validity, back.validity)
        back_len = back.cover_end - back.cover_start
        behind = True
    lat = cov.lateral if lateral is None else lateral
    if lat > 0.0:
        ahead = cover_end - s  # `Coverage._lateral_ahead`
        if not has_route:
            d = _advance_d(_max(v, 0.0), a, vmax, AHEAD_TIME)
            d = margin + (d if d > AHEAD_MIN else AHEAD_MIN)
            ahead = d if d < ahead else ahead
        _add(cells, _lateral(cov, trk, path, s, ahead, behind, back_len,
                             cov.route.edge_ids if has_route else None, lat))
    return _occ.make_occupation(tuple(cells), _wire(validity), o[2], o[3], o[4], cover_end)


cdef list _lateral(cov, trk, path, double s, double ahead, bint behind, double back_len, only, double lat):
    """`Coverage._lateral_cells` (`behind` False: `back_len` is the default, the margin and the body)."""
    near = near_index(trk.placer)
    cdef double back = back_len if behind else cov.margin + cov.body
    cdef list out = near.path_cells(path, s, lat, back, ahead, only)
    if only is not None:
        return out
    x, y = path.xy(s)
    area_cell = cov.net.area_cell
    for area in near.areas_near(x, y, lat):  # an area next to the way: maybe inside it
        if near.within_ring(area, x, y, lat):
            c = area_cell[area]
            if c not in out:
                out.append(c)
    return out
