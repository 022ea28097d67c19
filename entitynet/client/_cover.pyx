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

from libc.math cimport INFINITY, fabs, isfinite, sqrt

from entitynet.client._occupy cimport occupy_parts

from entitynet.client import kinematics as _kin
from entitynet.client import limits as _lim
from entitynet.client import occupation as _occ
from entitynet.client.motion import NetworkModel
from entitynet.client.lateral import near_index

#: `coverage.MAX_PUBLISH_CELLS`, `LATERAL_AHEAD_TIME` and `LATERAL_AHEAD_MIN` (coverage.py imports this module, so
#: they are written here too, and a test holds them equal: `constants()`); the others read from their homes
cdef Py_ssize_t MAX_CELLS = 64
cdef double AHEAD_TIME = 12.0
cdef double AHEAD_MIN = 10.0
cdef double A_EPS = _kin.A_EPS
cdef double D_EPS = _kin.D_EPS
cdef double HORIZON = _lim.HORIZON
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


cdef double _travel_time(double d, double v, double a, double vmax) except? -1.0:
    """`kinematics.time_to_travel(d, v, a, vmax)`: the same operations in the same order (C's `sqrt` is IEEE's, as
    `math.sqrt` is); a division by zero raises ZeroDivisionError as Python's does, a negative `sqrt` argument
    ValueError (neither happens for a published ghost, whose speed is not negative)."""
    cdef double t_cap, d_cap, disc, den
    if not d > D_EPS:
        return 0.0
    a = 0.0 if (-A_EPS < a and a < A_EPS) else a
    if a > 0.0 and v < vmax:
        t_cap = (vmax - v) / a
        d_cap = v * t_cap + 0.5 * a * t_cap * t_cap
        if d > d_cap:
            return t_cap + (d - d_cap) / vmax if vmax > 0.0 else INFINITY
        disc = v * v + 2.0 * a * d
        if disc < 0.0:
            raise ValueError("math domain error")
        den = v + sqrt(disc)
        if den == 0.0:
            raise ZeroDivisionError("float division by zero")
        return 2.0 * d / den
    if a < 0.0:
        disc = v * v + 2.0 * a * d
        if disc < 0.0:
            return INFINITY
        den = v + sqrt(disc)
        return 2.0 * d / den if den > 0.0 else INFINITY
    return d / v if v > 0.0 else INFINITY


cdef class GhostTravel:
    """`NetworkModel.time_to` of one ghost as a C callable (what `occupy` asks once a publish for the front's
    period): the ghost's numbers read once, no Python frame per call. Only for a ghost of type `NetworkModel`
    itself (a subclass may answer otherwise); tests/entitynet/client/test_cover_compiled.py holds it equal."""
    cdef double s0, v, a, vmax, tb, sb, vb, b

    def __init__(self, ghost):
        self.s0, self.v, self.a, self.vmax = ghost.s0, ghost.v, ghost.a, ghost.vmax
        self.tb, self.sb, self.vb, self.b = ghost.plan

    def __call__(self, double d):
        cdef double t
        if not isfinite(self.tb) or self.s0 + d <= self.sb:
            t = _travel_time(d, self.v, self.a, self.vmax)
        elif not isfinite(self.b):  # `NetworkModel._brake_time`
            t = INFINITY
        else:
            t = self.tb + _travel_time(self.s0 + d - self.sb, self.vb, -self.b, self.vb)
        return t if t <= HORIZON else INFINITY


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
                                0.5, path.edges[-1] == trk.dead_end,
                                GhostTravel(ghost) if type(ghost) is NetworkModel else ghost.time_to, 40.0)
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
