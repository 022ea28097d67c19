# cython: language_level=3, boundscheck=False, wraparound=False
# distutils: extra_compile_args = -ffp-contract=off
"""`Path.xy` compiled (entitynet/client/path.py; the pure method is the reference, used where pip did not build
this module): the point at a path coordinate, asked about twice a fix (the ghost's drift test, the estimate)
and three times a publish (the lateral cover). The same comparisons, bisections and IEEE operations in the same
order (no multiply-add contraction). tests/entitynet/client/test_lateral.py holds both equal. The lists are
read with bounds checks and negative indices as Python reads them (`boundscheck`, `wraparound`): a malformed
edge of one geometry point or none gives the pure method's answer or its IndexError, not stray memory."""

cimport cython

from entitynet.client._bisect cimport bisect_right


@cython.boundscheck(True)
@cython.wraparound(True)
def path_xy(path, double s):
    """Local (x, y) at path coordinate s, clamped to the path (`Path.xy`)."""
    cdef list cum = path.cum, edges = path.edges
    cdef Py_ssize_t ne = len(edges), k, lo, hi
    k = bisect_right(cum, s, 0, len(cum)) - 1
    if k < 0:
        k = 0
    elif k >= ne:
        k = ne - 1
    e, d_ = edges[k]
    net = path.net
    cdef Py_ssize_t ei = e
    cdef double length = net.edge_len[ei]
    cdef double d = s - <double>cum[k]
    d = 0.0 if d < 0.0 else (length if d > length else d)
    cdef double offset = d if d_ > 0 else length - d
    cdef list geom_off = net.geom_off, gcum = net.gcum, gx = net.gx, gy = net.gy
    lo, hi = geom_off[ei], geom_off[ei + 1]
    if offset <= 0.0:
        return gx[lo], gy[lo]
    if offset >= <double>gcum[hi - 1]:
        return gx[hi - 1], gy[hi - 1]
    if hi - lo == 2:
        k = lo
    else:
        k = bisect_right(gcum, offset, lo, hi) - 1
        k = min(max(k, lo), hi - 2)
    cdef double c0 = gcum[k]
    cdef double seg = <double>gcum[k + 1] - c0
    cdef double t = 0.0 if seg <= 0.0 else (offset - c0) / seg
    cdef double x0 = gx[k], y0 = gy[k]
    return x0 + t * (<double>gx[k + 1] - x0), y0 + t * (<double>gy[k + 1] - y0)
