# cython: language_level=3, boundscheck=False, wraparound=False
# distutils: extra_compile_args = -ffp-contract=off
"""`payload.encode_network`'s quantisation compiled (entitynet/client/payload.py; the pure function is the
reference, used where pip did not build this module or with ENTITYNET_PURE_PYTHON=1): every publish of the
network model rounds ten numbers, builds the body and the ghost, and as Python that was a tenth of a publish
(issue 22). `round` is Python's `float.__round__()` written out (C's `round`, then half-way cases to even, as
CPython's float___round___impl does), the products and quotients the same IEEE operations (no multiply-add
contraction: `-ffp-contract=off`); a non-finite field, or a product too large for an int, goes to the pure
function, which raises as before. tests/entitynet/client/test_payload_compiled.py holds both equal, bytes and
ghost, on half-way values, -0.0, NaN, infinities and huge values."""

from cpython.long cimport PyLong_FromDouble
from libc.math cimport INFINITY, fabs, isfinite
from libc.math cimport round as c_round


cdef inline double _round(double x) noexcept:
    """Python's round(x) of a float, as the double of the int it returns (so -0.0 comes out 0.0: the reference
    divides that int, and int 0 / 100.0 is 0.0)."""
    cdef double r = c_round(x)
    if fabs(x - r) == 0.5:
        r = 2.0 * c_round(x / 2.0)
    return r + 0.0  # -0.0 + 0.0 is +0.0 (round to nearest); any other value is itself


def encode_network(double t0, path, double s0, double v, double a, double vmax, etype, parts,
                   double stop_s, double brake, pack, make_ghost, reference, version, kind):
    """`payload.encode_network(t0, path, ...)`: (payload bytes, ghost). `pack` the payload module's packer,
    `make_ghost` `motion.network_model`, `reference` the pure function (the non-finite cases go there)."""
    cdef double t0r, s0r, vr, ar, vmaxr, stopr, braker, p
    cdef bint stop_finite = isfinite(stop_s)
    v = 0.0 if 0.0 > v else v  # max(v, 0.0), as the builtin chooses
    t0r = _round(t0 * 1000.0)
    s0r = _round(s0 * 100.0)
    vr = _round(v * 1000.0)
    ar = _round(a * 1000.0)
    vmaxr = _round(vmax * 1000.0)
    braker = _round(brake * 1000.0)
    stopr = _round(stop_s * 100.0) if stop_finite else -1.0
    if not (isfinite(t0r) and isfinite(s0r) and isfinite(vr) and isfinite(ar) and isfinite(vmaxr)
            and isfinite(braker) and isfinite(stopr)):
        return reference(t0, path, s0, v, a, vmax, etype, parts, stop_s, brake)
    cdef list partsi = []
    cdef list partsf = []
    for q in parts:
        p = _round(<double>q * 100.0)
        if not isfinite(p):
            return reference(t0, path, s0, v, a, vmax, etype, parts, stop_s, brake)
        partsi.append(PyLong_FromDouble(p))
        partsf.append(p / 100.0)
    cdef list signed = []
    cdef long e, d
    for de in path.edges:
        e, d = de
        signed.append((e + 1) * d)
    body = [version, kind, PyLong_FromDouble(t0r), etype, PyLong_FromDouble(s0r), PyLong_FromDouble(vr),
            PyLong_FromDouble(ar), PyLong_FromDouble(vmaxr), partsi, signed,
            PyLong_FromDouble(stopr) if stop_finite else -1, PyLong_FromDouble(braker)]
    ghost = make_ghost(t0r / 1000.0, path, s0r / 100.0, vr / 1000.0, ar / 1000.0, vmaxr / 1000.0, etype,
                       tuple(partsf), stopr / 100.0 if stop_finite else INFINITY, braker / 1000.0)
    return pack(body), ghost
