# The compiled outboxes' C layout, shared with the compiled route (`_fanout.pyx` cimports `OutboxTable`).
from cpython.ref cimport PyObject


cdef struct Item:
    Py_ssize_t slot  # the entity's slot in the table
    PyObject *enc  # NULL: the entity's shared current bytes (`Ent.cur`); else this viewer's own (a reference)


cdef struct Box:
    Item *items  # pending states in first-queued order
    Py_ssize_t n
    Py_ssize_t cap


cdef struct Ent:
    PyObject *cur  # the bytes every plain item of this slot reads (a reference; NULL while none pending)
    PyObject *eid  # the entity id (a reference), the slot's key in `OutboxTable.slot_of`
    Py_ssize_t pending  # items of this slot in all boxes
    Py_ssize_t plain  # ... of which read `cur`
    bint released  # the entity is gone: the slot is freed when nothing is pending


cdef class OutboxTable:
    cdef Box *boxes
    cdef Ent *ents
    cdef unsigned long long **blk  # the 2-bit matrix in blocks (NULL: all 0), (ecap >> BR) x (vcap >> BV)
    cdef int *blk_n  # per block: its entries that are not 0 (the block is pooled when none is left)
    cdef unsigned long long **pool  # emptied blocks (all 0) kept for reuse, at most POOL_MAX
    cdef Py_ssize_t n_pool, n_blocks
    cdef unsigned int *vstamp
    cdef int *vslot_of
    cdef Py_ssize_t vcap, ecap, nbv, n_cid, n_vslots, n_eslots
    cdef unsigned int fgen
    cdef dict slot_of
    cdef list free_vs, free_es
    cdef dict _boxes
    cdef Py_ssize_t f_slot, f_before, f_hits, f_kbase, f_wbase  # the fan-out's slot; its block row, word row
    cdef PyObject *f_prev
    cdef bint f_active
    cdef readonly Py_ssize_t max_states, max_control

    cdef Py_ssize_t slot_for(self, object eid) except -1
    cdef int vslot(self, long cid) noexcept
    cdef int begin_plain(self, Py_ssize_t s, bytes enc) except -1
    cdef int put_plain(self, int vs) except -1
    cdef int end_plain(self) except -1
    cdef int put_enc(self, int vs, Py_ssize_t s, bytes enc) except -1
    cdef int _new_vslot(self) except -1
    cdef int _grow_v(self, Py_ssize_t need) except -1
    cdef int _grow_e(self, Py_ssize_t need) except -1
    cdef int _append(self, int vs, Py_ssize_t s, PyObject *enc) except -1
    cdef Py_ssize_t _find(self, int vs, Py_ssize_t s) noexcept
    cdef void _release(self, int vs, Item *it) noexcept
    cdef void _free_ent(self, Py_ssize_t s) noexcept
    cdef Py_ssize_t _fit(self, int vs, Py_ssize_t n_max, Py_ssize_t b_max, Py_ssize_t size, bint nonempty) noexcept
    cdef Py_ssize_t _size(self, int vs) noexcept
    cdef bytes _join_take(self, int vs, Py_ssize_t k)
    cdef list _list_take(self, int vs, Py_ssize_t k)
    cdef void _drop(self, int vs, Py_ssize_t k) noexcept
    cdef void _close_box(self, int vs) noexcept


cdef class COutbox:
    cdef OutboxTable table
    cdef int vs
    cdef list _control
    cdef bint _overflow, _close_after
    cdef readonly Py_ssize_t max_states, max_control
