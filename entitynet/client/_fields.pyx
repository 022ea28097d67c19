# cython: language_level=3, boundscheck=True, wraparound=True
# distutils: extra_compile_args = -ffp-contract=off
"""`Player._network_fields` compiled (entitynet/client/player.py; the pure method is the reference, used where pip
did not build this module or with ENTITYNET_PURE_PYTHON=1): the fields of the network model a publish sends.

Why: about a sixth of a publish's CPU in the city simulation was this method's Python (issue 22): a dozen
attribute reads, the standing position's mean, the clamps, the path's index and suffix. The reads of the entity's
state stay the Python properties that own them (the row's filter, path, recent coordinates, peak speed; the
estimate's `motion`; the route's `next_stop`), so each field keeps one home; the arithmetic and the path's
bisection and suffix are C.

Exactness: the same IEEE operations in the reference's order (`-ffp-contract=off`); `min` and `max` as Python's
builtins choose (the first argument unless the second is strictly smaller / larger), so NaN and -0.0 come out
alike; the standing position's mean is Python's own `sum` (its summation order is the interpreter's); the
bisection is `bisect.bisect_right`'s (a NaN bound ends at the last edge, as there). Values that are not floats
(an injected estimate's ints) take the pure method. tests/entitynet/client/test_fields_compiled.py holds the two
equal bit for bit."""

from libc.math cimport INFINITY

from entitynet.client._bisect cimport bisect_right

from entitynet.client.motion import NetworkModel
from entitynet.client.path import Path


cdef inline double _min(double a, double b):
    """Python's min(a, b) of two floats."""
    return b if b < a else a


cdef inline double _max(double a, double b):
    """Python's max(a, b) of two floats."""
    return b if b > a else a


def network_fields(player, t, bint from_ghost, stop_at, reference):
    """`Player._network_fields(t, from_ghost, stop_at)` (`reference`: the pure method, for what is not a float)."""
    et = player.etype
    if type(et.vmax) is not float or type(et.v_stop) is not float or type(et.amax) is not float:
        return reference(player, t, from_ghost, stop_at)
    trk = player.tracker
    ghost = player.ghost
    cdef double s, v, a, vmax, s_sub, v_stop = et.v_stop, etv = et.vmax, amax
    if from_ghost and isinstance(ghost, NetworkModel):
        if stop_at is not None:
            s, v, a = ghost.s_at(stop_at), 0.0, 0.0
        else:
            s, v, a = ghost.s_at(t), ghost.speed_at(t), ghost.a
        path = ghost.path
    else:
        kf = trk.kf
        s_o = kf.s
        va = (kf.v, kf.a) if from_ghost else player.estimate.motion(player, t)
        if type(s_o) is not float or type(va[0]) is not float or type(va[1]) is not float:
            return reference(player, t, from_ghost, stop_at)
        s, v, a = s_o, va[0], va[1]
        path = trk.path
        if player.rules.reposition:
            v = a = 0.0
        if v < v_stop:
            recent = trk.recent_s
            if len(recent) >= 2:
                # standing: the mean of the last fixes is a better position than the lagging filter
                near = recent[-3:]
                s = sum(near) / len(near)
    if v < v_stop:
        v, a = 0.0, 0.0
    v = _min(v, etv)  # a noisy filter must not publish a walker at 6 m/s
    if et.accel:
        amax = et.amax
        a = _min(_max(a, -amax), amax)
    else:
        a = 0.0
    cdef double start_s = s - <double>player.body - <double>player.margin
    cdef list cum = path.cum, edges = path.edges
    cdef Py_ssize_t n = len(edges), k0 = bisect_right(cum, start_s, 0, len(cum)) - 1  # `Path.index`
    if k0 < 0:
        k0 = 0
    elif k0 >= n:
        k0 = n - 1
    cdef double c0 = cum[k0]
    sub = path.suffix(k0)
    s_sub = s - c0
    # an accelerating vehicle is expected to reach its usual cruising speed, not the type's maximum
    vmax = etv
    if a > 0.0:
        vpeak = trk.vpeak
        if vpeak > v:
            vmax = _min(_max(vpeak, 4.0), etv)
    stop_s = player.route.next_stop(sub, s_sub) if v > 0.0 else INFINITY
    return t, sub, s_sub, _max(v, 0.0), a, vmax, et.code, et.parts, stop_s, et.brake
