# cython: language_level=3, boundscheck=False, wraparound=False
"""The viewers' shared frame decoder's walk in C (`message_cache.MessageCache.decode`, issue 23).

Why: at 8,000 entities and 800 viewers a real-time tick delivers about 159,000 messages to the simulation's
viewers, and the Python walk (msgpack's `Unpacker.skip` and `tell` per message, a slice, a dict lookup) cost about
0.75 us each: the largest single part of the coordinator's tick after the fleet. msgpack's Python API has no call
that gives where each element of an array ends, so this walks the frame itself: it reads the array header, finds
the end of each message by the msgpack format's type bytes (the format's own rules; it builds no objects), and
looks each message's bytes up in the cache's tables.

It never decides a message's validity: a message in none of the tables goes to the cache's `_decode_new` (the
codec, alone on that message), and any frame it does not take whole (not one array, more than `max_messages`, a
truncated or trailing object, the never-used byte 0xc1) returns None, and the caller hands the frame to the codec
for the answer or the error. So every message it returns either came from the codec now or has the very bytes of
one that did: the same messages as the pure walk (tests/sims/engine/test_message_cache.py runs both)."""

from cpython.bytes cimport PyBytes_AS_STRING, PyBytes_FromStringAndSize, PyBytes_GET_SIZE
from cpython.dict cimport PyDict_GetItem
from cpython.list cimport PyList_Append
from cpython.object cimport PyObject


cdef inline unsigned long long _be(const unsigned char* p, int k) noexcept nogil:
    """A k-byte big-endian unsigned integer (msgpack's lengths and counts)."""
    cdef unsigned long long v = 0
    cdef int j
    for j in range(k):
        v = (v << 8) | p[j]
    return v


cdef inline Py_ssize_t _past_sized(const unsigned char* p, Py_ssize_t i, Py_ssize_t n, int k,
                                   int extra) noexcept nogil:
    """Past a sized object's body whose k-byte length starts at `i` (then `extra` bytes: ext's type byte, then
    the data), or -1 where it does not fit within `n` bytes."""
    cdef unsigned long long ln
    if i + k > n:
        return -1
    ln = _be(p + i, k)
    if ln + extra > <unsigned long long>(n - i - k):
        return -1
    return i + k + extra + <Py_ssize_t>ln


cdef Py_ssize_t _end_of(const unsigned char* p, Py_ssize_t i, Py_ssize_t n) noexcept nogil:
    """The offset just past the msgpack object that starts at `i` (its nested elements included), or -1 where it
    does not end within `n` bytes or holds the never-used byte 0xc1. Counts the objects still to pass instead of
    recursing: every object takes at least one byte, so more pending than bytes left is a truncation."""
    cdef long long pending = 1
    cdef unsigned long long ln
    cdef unsigned char b
    cdef int k
    while pending > 0:
        if i >= n:
            return -1
        b = p[i]
        i += 1
        pending -= 1
        if b <= 0x7f or b >= 0xe0:  # positive and negative fixint
            continue
        if b <= 0x8f:  # fixmap: keys and values
            pending += 2 * (b & 0x0f)
        elif b <= 0x9f:  # fixarray
            pending += b & 0x0f
        elif b <= 0xbf:  # fixstr
            i += b & 0x1f
        elif b == 0xc0 or b == 0xc2 or b == 0xc3:  # nil, false, true
            continue
        elif b == 0xc1:
            return -1
        elif b <= 0xc6:  # bin 8, 16, 32
            i = _past_sized(p, i, n, 1 << (b - 0xc4), 0)
            if i < 0:
                return -1
        elif b <= 0xc9:  # ext 8, 16, 32: length, type byte, data
            i = _past_sized(p, i, n, 1 << (b - 0xc7), 1)
            if i < 0:
                return -1
        elif b == 0xca:  # float 32
            i += 4
        elif b == 0xcb:  # float 64
            i += 8
        elif b <= 0xcf:  # uint 8, 16, 32, 64
            i += 1 << (b - 0xcc)
        elif b <= 0xd3:  # int 8, 16, 32, 64
            i += 1 << (b - 0xd0)
        elif b <= 0xd8:  # fixext 1, 2, 4, 8, 16: type byte, data
            i += 1 + (1 << (b - 0xd4))
        elif b <= 0xdb:  # str 8, 16, 32
            i = _past_sized(p, i, n, 1 << (b - 0xd9), 0)
            if i < 0:
                return -1
        else:  # array 16, 32 (0xdc, 0xdd) and map 16, 32 (0xde, 0xdf)
            k = 2 if b == 0xdc or b == 0xde else 4
            if i + k > n:
                return -1
            ln = _be(p + i, k)
            i += k
            if b >= 0xde:
                ln *= 2
            if ln > <unsigned long long>(n - i):
                return -1
            pending += <long long>ln
        if pending > n - i:
            return -1
    return i if i <= n else -1


def walk(bytes payload, cache, Py_ssize_t max_messages, object out):
    """Append the frame's messages to `out` (a list or a subclass of it), for `cache`, a
    `message_cache.MessageCache`: each message's bytes looked up in its tick's table (`_messages`), else in its
    kept generations (`_kept`, `_kept_old`; then recorded as `_decode_new` records it), else handed to
    `cache._decode_new(piece, size)` (None: refused), which also takes every case that would start a new
    generation or clear the table. Returns (messages not in the tick's table, offset of the first message), or
    None where the frame is not taken whole (the caller asks the codec then; `out` may hold part of the frame)."""
    cdef const unsigned char* p = <const unsigned char*>PyBytes_AS_STRING(payload)
    cdef Py_ssize_t n = PyBytes_GET_SIZE(payload), i, end, first, misses = 0
    cdef Py_ssize_t keep = cache.keep, max_known = cache.max_entries
    cdef unsigned long long count, j
    cdef unsigned char b
    cdef PyObject* hit
    cdef bint promote
    cdef dict known = cache._messages, sizes = cache._sizes, kept = cache._kept, old = cache._kept_old
    new, on_new = cache._decode_new, cache.on_new
    if n < 1:
        return None
    b = p[0]
    if 0x90 <= b <= 0x9f:
        count, i = b & 0x0f, 1
    elif b == 0xdc and n >= 3:
        count, i = _be(p + 1, 2), 3
    elif b == 0xdd and n >= 5:
        count, i = _be(p + 1, 4), 5
    else:
        return None
    if count > <unsigned long long>max_messages or count > <unsigned long long>(n - i):
        return None
    first = i
    for j in range(count):
        end = _end_of(p, i, n)
        if end < 0:
            return None
        piece = PyBytes_FromStringAndSize(<const char*>p + i, end - i)
        hit = PyDict_GetItem(known, piece)
        if hit is not NULL:
            PyList_Append(out, <object>hit)
            i = end
            continue
        misses += 1
        # kept from an earlier tick: recorded here unless that would start a generation or clear the table
        promote = False
        if len(known) < max_known:
            hit = PyDict_GetItem(kept, piece)
            if hit is NULL and len(kept) < keep:
                hit = PyDict_GetItem(old, piece)
                promote = True
        if hit is not NULL:
            m = <object>hit
            if promote:
                kept[piece] = m
            known[piece] = m
            sizes[id(m)] = (m, end - i)
            if on_new is not None:
                on_new(m)
        else:
            m = new(piece, end - i)
            if m is None:
                return None
            known, sizes, kept, old = cache._messages, cache._sizes, cache._kept, cache._kept_old
        PyList_Append(out, m)
        i = end
    if i != n:
        return None
    return misses, first
