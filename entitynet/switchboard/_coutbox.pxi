# One client's outbox over the compiled table (`_outbox.pyx` includes this file: one extension module,
# kept apart so that each source file stays small). The `Outbox` API of entitynet/switchboard/outbox.py.


@cython.auto_pickle(False)  # a copy would share the viewer slot, and both would give it back
cdef class COutbox:
    """One client's pending messages (the `Outbox` API): its states in the table's C arrays, a control FIFO."""

    def __cinit__(self, OutboxTable table not None):
        """Only with a table (`OutboxTable.open` makes them): the outbox takes a viewer slot of its own."""
        self.vs = table._new_vslot()
        self.table, self._control = table, []
        self.max_states, self.max_control = table.max_states, table.max_control

    def __copy__(self):
        raise TypeError("a COutbox cannot be copied (it owns a viewer slot of its table)")

    def __deepcopy__(self, memo):
        raise TypeError("a COutbox cannot be copied (it owns a viewer slot of its table)")

    def __reduce__(self):
        raise TypeError("a COutbox cannot be pickled (it owns a viewer slot of its table)")

    def __dealloc__(self):
        if self.table is not None:
            self.table._close_box(self.vs)

    def __len__(self):
        return self.table.boxes[self.vs].n + len(self._control)

    @property
    def close_after(self):
        """The connection is to be closed once what is queued has been written (a fatal ERROR is queued)."""
        return self._close_after

    @property
    def has_control(self):
        """Replies are waiting: a shell writes them now, not at the next flush."""
        return bool(self._control)

    @property
    def n_states(self):
        """Entity states pending (at most one per entity)."""
        return self.table.boxes[self.vs].n

    @property
    def n_control(self):
        """Replies pending."""
        return len(self._control)

    @property
    def over_bounds(self):
        """More is pending than the bounds allow: the client does not keep up (the core drops it)."""
        return self._overflow or self.table.boxes[self.vs].n > self.max_states \
            or len(self._control) > self.max_control

    def put_state(self, object entity, bytes encoded not None):
        """Queue an entity's latest state, replacing one still pending (in its place)."""
        self.table.put_enc(self.vs, self.table.slot_for(entity), encoded)

    def put_control(self, bytes encoded not None):
        """Queue a reply; beyond `max_control` the client is marked over its bounds instead."""
        if len(self._control) >= self.max_control:
            self._overflow = True
            return
        self._control.append(encoded)

    def put_last_word(self, bytes encoded not None):
        """Queue a fatal ERROR beyond the bound (it must go out) and close once it is written."""
        self._control.append(encoded)
        self._close_after = True

    def discard_states(self):
        """Forget the pending states."""
        self.table._drop(self.vs, self.table.boxes[self.vs].n)

    def discard(self):
        """Forget everything pending and the overflow mark."""
        self.discard_states()
        self._control.clear()
        self._overflow = False

    def take_states(self, Py_ssize_t max_messages, Py_ssize_t sure_fit, Py_ssize_t max_body):
        """`Outbox.take_states_py`: all pending states as (count, joined bytes) when only states are pending, at
        most `max_messages` of them and within `max_body` bytes (certain below `sure_fit`); else None."""
        cdef Py_ssize_t n = self.table.boxes[self.vs].n
        if 0 < n <= max_messages and not self._control and not self._close_after and not self._overflow:
            if n <= sure_fit or self.table._size(self.vs) <= max_body:
                return n, self.table._join_take(self.vs, n)
        return None

    def holds_few(self, Py_ssize_t k):
        """`Outbox.holds_few`: only states pending, fewer than `k` of them."""
        cdef Py_ssize_t n = self.table.boxes[self.vs].n
        return 0 < n < k and not self._control and not self._close_after and not self._overflow

    def drain(self, max_messages=None, max_bytes=None):
        """`Outbox.drain`: control first, then states in first-queued order, within the bounds (at least one)."""
        cdef list control = self._control, out
        cdef Py_ssize_t n_max, b_max, size = 0, i, n = self.table.boxes[self.vs].n
        self._control = []
        if max_messages is None and max_bytes is None:
            control.extend(self.table._list_take(self.vs, n))
            return control
        n_max = len(control) + n if max_messages is None else max(1, max_messages)
        b_max = -1 if max_bytes is None else max_bytes
        out = []
        for i in range(len(control)):
            m = control[i]
            if len(out) >= n_max or (out and b_max >= 0 and size + len(m) > b_max):
                self._control = control[i:]
                return out
            out.append(m)
            size += len(m)
        out.extend(self.table._list_take(self.vs, self.table._fit(self.vs, n_max - len(out), b_max, size,
                                                                      bool(out))))
        return out
