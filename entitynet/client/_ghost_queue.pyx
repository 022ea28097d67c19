# cython: language_level=3, boundscheck=False, wraparound=False
"""`ghost_table.queue_messages` compiled (entitynet/client/ghost_table.py; the pure function is the reference,
used where pip did not build this module or with ENTITYNET_PURE_PYTHON=1). Why: a simulation's viewers receive
every UPDATE once per viewer of its cells (about 330,000 deliveries per 0.5 s tick at 10,000 entities and 1,000
viewers), and the table's per-message step (find the message's version, check the (entity, viewer) pair, queue
it) was a Python loop of about a microsecond per delivery. Here the same steps run over the same Python
containers through the C API, in the same order, with the same callbacks (`new_version`, `flush`), so the
queue and the table come out identical (tests/entitynet/client/test_ghost_queue_compiled.py holds them equal
on hostile frames)."""


def queue_messages(object msgs, object col, dict version_of, list rows, dict row_of, set pairs, list q_col,
                   list q_ver, type update, object new_version, object flush, object now):
    """Queue `msgs` (UPDATEs and LEAVEs, in order) for column `col`; how many were LEAVEs. As the reference."""
    cdef Py_ssize_t leaves = 0
    cdef long long c = col
    cdef long long r
    cdef object m, ver, key
    for m in msgs:
        if type(m) is update:
            ver = version_of.get(id(m))
            if ver is None:
                ver = new_version(m, now)
            r = rows[ver]
        else:
            leaves += 1
            r = row_of.get(m.entity, -1)
            if r < 0:
                continue  # LEAVE of an entity no viewer holds
            ver = -1 - r
        key = (r << 24) | c
        if key in pairs:
            flush()
        pairs.add(key)
        q_col.append(col)
        q_ver.append(ver)
    return leaves
