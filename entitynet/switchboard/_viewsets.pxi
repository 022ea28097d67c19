# Sets of client ids in C (`_fanout.pyx` includes this file: one extension module, kept apart so that each source
# file stays small): the compiled switchboard's cell -> subscribers sets, entity viewer sets and dirty marks.
#
# Why: the route's work per PUBLISH was, per viewer, a step of a Python set's iteration, a Python int read, a
# `PySet_Add` into the new viewer set and one into the dirty set (the profile: `_PySet_NextEntry`,
# `set_add_entry`, `set_dealloc`, malloc: about a third of the route). Here a set is a sorted array of 64-bit
# words (`W`: word index, bits), so the union of a PUBLISH's cells, who gains, keeps and loses the entity, and
# the dirty marks are word operations (OR, AND NOT, popcount), and only the stores are per viewer.
# Memory: 16 bytes per non-empty word of 64 ids (at most 16 bytes per member, 1,000 viewers in 16 words: 256
# bytes), where a Python set of a few hundred ints holds a table of 512-1,024 16-byte entries.

cdef extern from *:
    int __builtin_ctzll(unsigned long long) nogil
    int __builtin_popcountll(unsigned long long) nogil

cdef struct W:
    long long idx  # ids idx * 64 .. idx * 64 + 63 ...
    unsigned long long bits  # ... the members among them (never 0 in a set's array)

cdef long long _MAX_ID = (1 << 40) - 1  # far beyond any client id (the compiled outboxes refuse ids >= 2**28)
cdef long long _MAX_MARK = (1 << 28) - 1  # `_outbox.MAX_CID`: the dirty bitmap is dense, 32 MiB at most


cdef inline long long _as_id(object v) except -2:
    """`v` as an id in [0, _MAX_ID], else -1 (not an int, negative, too large)."""
    cdef int overflow = 0
    cdef long long x
    if type(v) is not int and not isinstance(v, int):
        return -1
    x = PyLong_AsLongLongAndOverflow(v, &overflow)
    if overflow != 0 or x < 0 or x > _MAX_ID:
        return -1
    return x


@cython.final
@cython.auto_pickle(False)
cdef class ViewerSet:
    """A set of client ids (the `set` API the core uses: add, discard, in, len, iteration, update, -, ==) over a
    sorted array of 64-bit words. The compiled route reads and builds these without Python objects."""

    cdef W *w
    cdef Py_ssize_t n, cap, count

    def __cinit__(self, object ids=()):
        for v in ids:
            self.add(v)

    def __dealloc__(self):
        free(self.w)

    def __reduce__(self):
        return ViewerSet, (list(self),)

    cdef Py_ssize_t _find(self, long long idx) noexcept:
        """The position of word `idx`, or where it would go (binary search)."""
        cdef Py_ssize_t lo = 0, hi = self.n, mid
        while lo < hi:
            mid = (lo + hi) >> 1
            if self.w[mid].idx < idx:
                lo = mid + 1
            else:
                hi = mid
        return lo

    cdef int _set_words(self, W *src, Py_ssize_t n) except -1:
        """Take a copy of `n` sorted words (zero words skipped) as the whole set."""
        cdef Py_ssize_t i, k = 0
        cdef W *w = NULL
        if n:
            w = <W *>malloc(n * sizeof(W))
            if w == NULL:
                raise MemoryError()
        free(self.w)
        self.w, self.cap, self.count = w, n, 0
        for i in range(n):
            if src[i].bits:
                w[k] = src[i]
                self.count += __builtin_popcountll(src[i].bits)
                k += 1
        self.n = k
        return 0

    def add(self, object cid):
        """Add a client id (a non-negative int below 2**40: ValueError else)."""
        cdef long long x = _as_id(cid), idx
        cdef unsigned long long bit
        cdef Py_ssize_t pos
        cdef W *grown
        if x < 0:
            raise ValueError(f"not a client id: {cid!r}")
        idx, bit = x >> 6, <unsigned long long>1 << (x & 63)
        pos = self._find(idx)
        if pos < self.n and self.w[pos].idx == idx:
            if not self.w[pos].bits & bit:
                self.w[pos].bits |= bit
                self.count += 1
            return
        if self.n == self.cap:
            grown = <W *>realloc(self.w, max(4, 2 * self.cap) * sizeof(W))
            if grown == NULL:
                raise MemoryError()
            self.w, self.cap = grown, max(4, 2 * self.cap)
        memmove(self.w + pos + 1, self.w + pos, (self.n - pos) * sizeof(W))
        self.w[pos].idx, self.w[pos].bits = idx, bit
        self.n += 1
        self.count += 1

    def discard(self, object cid):
        """Remove a client id if present."""
        cdef long long x = _as_id(cid), idx
        cdef unsigned long long bit
        cdef Py_ssize_t pos
        if x < 0:
            return
        idx, bit = x >> 6, <unsigned long long>1 << (x & 63)
        pos = self._find(idx)
        if pos < self.n and self.w[pos].idx == idx and self.w[pos].bits & bit:
            self.w[pos].bits &= ~bit
            self.count -= 1
            if not self.w[pos].bits:
                memmove(self.w + pos, self.w + pos + 1, (self.n - pos - 1) * sizeof(W))
                self.n -= 1

    def update(self, object ids):
        """Add every id of an iterable."""
        for v in ids:
            self.add(v)

    def __contains__(self, object cid):
        cdef long long x = _as_id(cid)
        cdef Py_ssize_t pos
        if x < 0:
            return False
        pos = self._find(x >> 6)
        return pos < self.n and self.w[pos].idx == (x >> 6) and (self.w[pos].bits >> (x & 63)) & 1 == 1

    def __len__(self):
        return self.count

    cdef list _list(self):
        """The members in ascending order."""
        cdef list out = []
        cdef Py_ssize_t i
        cdef unsigned long long b
        for i in range(self.n):
            b = self.w[i].bits
            while b:
                out.append((self.w[i].idx << 6) + __builtin_ctzll(b))
                b &= b - 1
        return out

    def __iter__(self):
        return iter(self._list())  # a snapshot: changing the set while iterating it is safe

    def __sub__(self, other):
        if not isinstance(self, ViewerSet):
            return NotImplemented
        return {v for v in (<ViewerSet>self)._list() if v not in other}

    def __eq__(self, other):
        if isinstance(other, ViewerSet):
            return self._list() == (<ViewerSet>other)._list()
        if isinstance(other, (set, frozenset)):
            return len(other) == self.count and all(v in other for v in self._list())
        return NotImplemented

    __hash__ = None

    def __repr__(self):
        return f"ViewerSet({self._list()!r})"


cdef ViewerSet _as_viewer_set(object s):
    """`s` itself when it is a `ViewerSet`, else a `ViewerSet` of its ids (a Python set left by other code)."""
    if type(s) is ViewerSet:
        return <ViewerSet>s
    return ViewerSet(s)


# scratch words for the union of a PUBLISH's cells (the core is single-threaded; grown, never shrunk)
cdef W *_ua = NULL
cdef W *_ub = NULL
cdef Py_ssize_t _ucap = 0


cdef int _ureserve(Py_ssize_t n) except -1:
    global _ua, _ub, _ucap
    cdef W *a
    cdef W *b
    if n <= _ucap:
        return 0
    n = max(n, 2 * _ucap, 64)
    a = <W *>realloc(_ua, n * sizeof(W))
    if a == NULL:
        raise MemoryError()
    _ua = a
    b = <W *>realloc(_ub, n * sizeof(W))
    if b == NULL:
        raise MemoryError()
    _ub, _ucap = b, n
    return 0


cdef inline void _ua_swap(W *merged) noexcept:
    """The merge wrote into `_ub`: it becomes `_ua` (and the old `_ua` the next scratch)."""
    global _ua, _ub
    _ub = _ua
    _ua = merged


cdef Py_ssize_t _merge(W *a, Py_ssize_t na, W *b, Py_ssize_t nb, W *out) noexcept:
    """The union of two sorted word arrays into `out` (room for na + nb words); returns its length."""
    cdef Py_ssize_t i = 0, j = 0, k = 0
    while i < na and j < nb:
        if a[i].idx < b[j].idx:
            out[k] = a[i]
            i += 1
        elif b[j].idx < a[i].idx:
            out[k] = b[j]
            j += 1
        else:
            out[k].idx, out[k].bits = a[i].idx, a[i].bits | b[j].bits
            i += 1
            j += 1
        k += 1
    while i < na:
        out[k] = a[i]
        i += 1
        k += 1
    while j < nb:
        out[k] = b[j]
        j += 1
        k += 1
    return k


cdef ViewerSet _union_of_cells(dict subs, tuple cells, long long skip):
    """The union of the subscriber sets of `cells`, without the id `skip` (the owner), as a new `ViewerSet`."""
    cdef ViewerSet s, out = ViewerSet()
    cdef Py_ssize_t n = 0, total = 0, i, pos
    cdef PyObject *p
    cdef list found = []
    for cell in cells:
        p = PyDict_GetItem(subs, cell)
        if p != NULL:
            s = _as_viewer_set(<object>p)
            if s.n:
                found.append(s)
                total += s.n
    if not found:
        return out
    _ureserve(total)
    for i in range(len(found)):
        s = <ViewerSet>found[i]
        if i == 0:
            memcpy(_ua, s.w, s.n * sizeof(W))
            n = s.n
        else:
            n = _merge(_ua, n, s.w, s.n, _ub)
            _ua_swap(_ub)
    if skip >= 0:
        pos = 0
        while pos < n and _ua[pos].idx < (skip >> 6):
            pos += 1
        if pos < n and _ua[pos].idx == (skip >> 6):
            _ua[pos].bits &= ~(<unsigned long long>1 << (skip & 63))
    out._set_words(_ua, n)
    return out


cdef int _cmp_ll(const void *a, const void *b) noexcept nogil:
    cdef long long x = (<const long long *>a)[0], y = (<const long long *>b)[0]
    return (x > y) - (x < y)


@cython.final
@cython.auto_pickle(False)
cdef class CidMarks:
    """The clients with news since the last `take_dirty` (the core's dirty set: add, discard, in, len, iteration,
    |=) as a bitmap over client ids, so that the route marks a word of 64 viewers with one OR, and the list of
    the words that became non-zero, so that `take` (the flush's `take_dirty`) visits those words only and clears
    them in place: its cost follows the clients with news, not the highest client id ever marked."""

    cdef unsigned long long *w
    cdef long long *touched  # words that went from 0 to non-zero since the last `take` (a word may recur)
    cdef Py_ssize_t nw, count, tcap
    cdef readonly Py_ssize_t nt  # entries of `touched` (readable for the tests: it must not grow without news)

    def __cinit__(self, object ids=()):
        self._grow(16)
        for v in ids:
            self.add(v)

    def __dealloc__(self):
        free(self.w)
        free(self.touched)

    def __reduce__(self):
        return CidMarks, (list(self),)

    cdef int _grow(self, Py_ssize_t need) except -1:
        cdef Py_ssize_t n
        cdef unsigned long long *w
        if need <= self.nw:
            return 0
        n = max(need, 2 * self.nw)
        w = <unsigned long long *>realloc(self.w, n * sizeof(unsigned long long))
        if w == NULL:
            raise MemoryError()
        memset(w + self.nw, 0, (n - self.nw) * sizeof(unsigned long long))
        self.w, self.nw = w, n
        return 0

    cdef int mark(self, long long idx, unsigned long long bits) except -1:
        """Mark the ids `bits` of word `idx`."""
        cdef unsigned long long new
        cdef long long *t
        if idx >= self.nw:
            if idx > (_MAX_MARK >> 6):
                raise ValueError("a client id beyond the compiled outboxes' bound")
            self._grow(idx + 1)
        new = bits & ~self.w[idx]
        if new:
            if self.w[idx] == 0:
                if self.nt == self.tcap:
                    t = <long long *>realloc(self.touched, max(16, 2 * self.tcap) * sizeof(long long))
                    if t == NULL:
                        raise MemoryError()
                    self.touched, self.tcap = t, max(16, 2 * self.tcap)
                self.touched[self.nt] = idx
                self.nt += 1
            self.count += __builtin_popcountll(new)
            self.w[idx] |= new
        return 0

    cdef list _ids(self, bint clear):
        """The marked ids in ascending order (with `clear`, the marks are emptied on the way)."""
        cdef list out = []
        cdef Py_ssize_t i
        cdef long long idx, prev = -1
        cdef unsigned long long b
        qsort(self.touched, self.nt, sizeof(long long), _cmp_ll)
        for i in range(self.nt):
            idx = self.touched[i]
            if idx == prev:
                continue
            prev = idx
            b = self.w[idx]
            while b:
                out.append((idx << 6) + __builtin_ctzll(b))
                b &= b - 1
            if clear:
                self.w[idx] = 0
        if clear:
            self.nt = self.count = 0
        return out

    def take(self):
        """The marked ids, ascending, as a list; the marks are empty afterwards (`take_dirty`)."""
        return self._ids(True)

    def add(self, object cid):
        """Mark a client id (a non-negative int below 2**28, the compiled outboxes' bound: ValueError else)."""
        cdef long long x = _as_id(cid)
        if x < 0 or x > _MAX_MARK:
            raise ValueError(f"not a client id the compiled outboxes take: {cid!r}")
        self.mark(x >> 6, <unsigned long long>1 << (x & 63))

    def discard(self, object cid):
        cdef long long x = _as_id(cid)
        cdef unsigned long long bit
        if x < 0 or (x >> 6) >= self.nw:
            return
        bit = <unsigned long long>1 << (x & 63)
        if self.w[x >> 6] & bit:
            self.w[x >> 6] &= ~bit
            self.count -= 1
            if self.count == 0:  # every word is zero: forget them, or a reader that writes its replies itself
                self.nt = 0      # (`written_out`, no flush) would grow `touched` by a word per reply for good

    def __ior__(self, other):
        cdef ViewerSet s
        cdef Py_ssize_t i
        if type(other) is ViewerSet:
            s = <ViewerSet>other
            for i in range(s.n):
                self.mark(s.w[i].idx, s.w[i].bits)
        else:
            for v in other:
                self.add(v)
        return self

    def __contains__(self, object cid):
        cdef long long x = _as_id(cid)
        return x >= 0 and (x >> 6) < self.nw and (self.w[x >> 6] >> (x & 63)) & 1 == 1

    def __len__(self):
        return self.count

    def __iter__(self):
        return iter(self._ids(False))

    def __eq__(self, other):
        if isinstance(other, (set, frozenset, CidMarks)):
            return len(other) == self.count and all(v in other for v in self)
        return NotImplemented

    __hash__ = None

    def __repr__(self):
        return f"CidMarks({list(self)!r})"
