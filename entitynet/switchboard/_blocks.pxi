# The (entity slot x viewer slot) 2-bit matrix of `_outbox.pyx` (included there: one extension module, kept apart
# so that each source file stays small). Blocks of 2**BR entity slots x 2**BV viewer slots, each allocated only
# while one of its entries is pending; a grid of block pointers (NULL: all 0) that grows without moving bits.

cdef enum:
    BR = 6  # a block has 2**BR entity slots (rows) ...
    BV = 8  # ... of 2**BV viewer slots (2 bits each)
    RMASK = (1 << BR) - 1
    VMASK = (1 << BV) - 1
    RWORDS = 8  # 64-bit words in a block's row: 2**BV / 32
    BWORDS = 512  # 64-bit words in a block: 2**BR * RWORDS
    POOL_MAX = 1024  # emptied blocks kept for reuse (4 MiB at most: no calloc churn from flush to flush)


# ---------------------------------------------------------------------------------------------- the 2-bit rows
# State of (entity slot, viewer slot): 0 nothing pending, 1 pending and reading the slot's `cur`, 3 pending with
# bytes of its own.
cdef inline Py_ssize_t _blk(OutboxTable t, Py_ssize_t s, int vs) noexcept:
    """The block position of (s, vs)."""
    return (s >> BR) * t.nbv + (vs >> BV)


cdef inline Py_ssize_t _word(Py_ssize_t s, int vs) noexcept:
    """The word of (s, vs) within its block."""
    return (s & RMASK) * RWORDS + ((vs & VMASK) >> 5)


cdef inline unsigned int _st(OutboxTable t, Py_ssize_t s, int vs) noexcept:
    cdef unsigned long long *b = t.blk[_blk(t, s, vs)]
    if b == NULL:
        return 0
    return (b[_word(s, vs)] >> ((vs & 31) * 2)) & 3


cdef void _unblock(OutboxTable t, Py_ssize_t k) noexcept:
    """Block `k` has nothing pending (all 0): to the pool, or freed when the pool is full."""
    if t.pool == NULL:
        t.pool = <unsigned long long **>calloc(POOL_MAX, sizeof(unsigned long long *))
    if t.pool != NULL and t.n_pool < POOL_MAX:
        t.pool[t.n_pool] = t.blk[k]
        t.n_pool += 1
    else:
        free(t.blk[k])
    t.blk[k] = NULL
    t.n_blocks -= 1


cdef inline void _set(OutboxTable t, Py_ssize_t s, int vs, unsigned long long st) noexcept:
    """Set the state of (s, vs); its block is there (`_reserve` before a 0 becomes pending; a pending entry's
    block stays until the entry is 0 again)."""
    cdef Py_ssize_t k = _blk(t, s, vs)
    cdef unsigned long long *w = &t.blk[k][_word(s, vs)]
    cdef int sh = (vs & 31) * 2
    cdef unsigned long long old = (w[0] >> sh) & 3
    w[0] = (w[0] & ~(<unsigned long long>3 << sh)) | (st << sh)
    if old == 0:
        if st != 0:
            t.blk_n[k] += 1
    elif st == 0:
        t.blk_n[k] -= 1
        if t.blk_n[k] == 0:
            _unblock(t, k)


cdef int _reserve(OutboxTable t, Py_ssize_t s, int vs) except -1:
    """The block of (s, vs) is there (from the pool, else zeroed memory): before an entry becomes pending."""
    cdef Py_ssize_t k = _blk(t, s, vs)
    if t.blk[k] != NULL:
        return 0
    if t.n_pool:
        t.n_pool -= 1
        t.blk[k] = t.pool[t.n_pool]
    else:
        t.blk[k] = <unsigned long long *>calloc(BWORDS, sizeof(unsigned long long))
        if t.blk[k] == NULL:
            raise MemoryError()
    t.n_blocks += 1
    return 0


cdef int _regrid(OutboxTable t, Py_ssize_t nbe, Py_ssize_t nbv) except -1:
    """The block grid resized to `nbe` x `nbv` positions (never smaller): the blocks keep their places."""
    cdef Py_ssize_t old_nbe = t.ecap >> BR, r
    blk = <unsigned long long **>calloc(max(nbe * nbv, 1), sizeof(unsigned long long *))
    cnt = <int *>calloc(max(nbe * nbv, 1), sizeof(int))
    if blk == NULL or cnt == NULL:
        free(blk)
        free(cnt)
        raise MemoryError()
    for r in range(old_nbe):
        memcpy(blk + r * nbv, t.blk + r * t.nbv, t.nbv * sizeof(unsigned long long *))
        memcpy(cnt + r * nbv, t.blk_n + r * t.nbv, t.nbv * sizeof(int))
    free(t.blk)
    free(t.blk_n)
    t.blk, t.blk_n, t.nbv = blk, cnt, nbv
    return 0
