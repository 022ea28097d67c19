# cython: language_level=3, boundscheck=False, wraparound=False
"""The compiled read path: `entitynet.server.hubpass.hub_ready_py` and `pong_now_py` without the interpreter's
per-step overhead.

Why: a lock step's PING costs the server more in Python around the system calls (a new bytes object per read,
the recogniser, the prefix, `os.writev` and its exception handling) than in the calls themselves. Here the read
goes into one reusable buffer, the PING shape is recognised and the PONG's prefix packed in C, and `read(2)` and
`writev(2)` are called directly (non-blocking sockets: the GIL is held, the calls return at once). Whether the
PONG may go now stays the core's (`Switchboard.pong_clear`); the PONG itself is encoded here, as `quick_pong`
encodes it. Same inputs, same effects, same bytes on the wire as the reference; tests compare them.
"""

from libc.errno cimport EAGAIN, EINTR, errno
from libc.math cimport isfinite, nearbyint
from libc.stdlib cimport free, malloc
from libc.string cimport memcpy
from posix.uio cimport iovec, writev
from posix.unistd cimport read
from cpython.bytes cimport PyBytes_FromStringAndSize

from entitynet import protocol as P


cdef extern from "<errno.h>":
    int EWOULDBLOCK

cdef unsigned long long MAX_INT = P.MAX_INT
cdef object Ping = P.Ping
cdef unsigned char PONG = P.PONG  # a positive fixint (< 0x80): checked at import below
if not 0 <= P.PONG < 0x80:
    raise ImportError("PONG's type code is not a msgpack fixint; rebuild _hubpass for the new code")

cdef char *_buf = NULL  # the reads' buffer, reused (grown to the largest read size asked for)
cdef Py_ssize_t _cap = 0


cdef inline long long _lone_ping(const unsigned char *d, Py_ssize_t n):
    """client_ms when d[:n] is one whole frame holding one PING in the canonical encoding, else -1
    (`entitynet.server.pingframe.lone_ping_ms`)."""
    cdef Py_ssize_t width, i
    cdef unsigned long long length, ms
    cdef unsigned char tag
    if n < 8 or n > 16 or d[4] != 0x91 or d[5] != 0x92 or d[6] != 0x0F:
        return -1
    length = (<unsigned long long>d[0] << 24) | (<unsigned long long>d[1] << 16) | (<unsigned long long>d[2] << 8) \
        | <unsigned long long>d[3]
    if length != <unsigned long long>(n - 4):
        return -1
    tag = d[7]
    if tag < 0x80:  # positive fixint
        return tag if n == 8 else -1
    if tag == 0xCC:
        width = 1
    elif tag == 0xCD:
        width = 2
    elif tag == 0xCE:
        width = 4
    elif tag == 0xCF:
        width = 8
    else:
        return -1
    if n != 8 + width:
        return -1
    ms = 0
    for i in range(width):
        ms = (ms << 8) | d[8 + i]
    return <long long>ms if ms <= MAX_INT else -1


def lone_ping_ms(bytes data):
    """`pingframe.lone_ping_ms` in C: client_ms or None."""
    cdef long long ms = _lone_ping(<const unsigned char *><char *>data, len(data))
    return None if ms < 0 else ms


def hub_ready(object server, object conn):
    """See `hub_ready_py`: the same read, the same effects.

    The shared buffer is read only between the `read(2)` and the next call into Python (which may let another
    thread's server run this function): a lone PING's bytes (at most 16) are copied to the stack first."""
    global _buf, _cap
    cdef Py_ssize_t size = server.config.read_size
    cdef bint mid = conn.decoder.mid_frame  # (only this reader feeds the decoder: asked before the read)
    cdef int fd = conn.fd
    cdef Py_ssize_t n
    cdef long long ms
    cdef int err = 0
    cdef char *grown
    cdef char ping[16]
    if size > _cap:
        grown = <char *>malloc(size)
        if grown == NULL:
            raise MemoryError()
        free(_buf)
        _buf = grown
        _cap = size
    while True:
        n = read(fd, _buf, size)
        if n >= 0:
            break
        err = errno
        if err != EINTR:
            break
    if n < 0:
        if err == EAGAIN or err == EWOULDBLOCK:
            return  # readable was reported but the bytes went elsewhere: the next poll tells
        n = 0  # closed under us or reset by the peer: as the end of the stream
    if n == 0:
        server._hub_eof(conn)
        return
    if not mid:
        ms = _lone_ping(<const unsigned char *>_buf, n)
        if ms >= 0:  # then n <= 16
            memcpy(ping, _buf, n)
            if not pong_now(server, conn, ms):
                server._hub_bytes(conn, PyBytes_FromStringAndSize(ping, n))
            return
    server._hub_bytes(conn, PyBytes_FromStringAndSize(_buf, n))


cdef inline Py_ssize_t _put_uint(unsigned char *p, unsigned long long v):
    """`v` as msgpack packs a non-negative int (the smallest of fixint, uint 8/16/32/64); the bytes written."""
    cdef Py_ssize_t width, i
    if v < 0x80:
        p[0] = <unsigned char>v
        return 1
    if v < 0x100:
        p[0] = 0xCC
        width = 1
    elif v < 0x10000:
        p[0] = 0xCD
        width = 2
    elif v < 0x100000000:
        p[0] = 0xCE
        width = 4
    else:
        p[0] = 0xCF
        width = 8
    for i in range(width):
        p[width - i] = <unsigned char>((v >> (8 * i)) & 0xFF)
    return 1 + width


cdef inline Py_ssize_t _pong_frame(unsigned char *f, unsigned long long client_ms, unsigned long long server_ms):
    """The frame of one PONG into f (at most 4 + 1 + 1 + 1 + 9 + 9 = 25 bytes): the 4-byte length, an array of
    one message, and `encode_message(Pong(client_ms, server_ms))`: [PONG, client_ms, server_ms] in msgpack.
    Returns the frame's length; the message is f[5:]."""
    cdef Py_ssize_t n = 5
    f[n] = 0x93  # an array of three
    f[n + 1] = PONG
    n += 2
    n += _put_uint(f + n, client_ms)
    n += _put_uint(f + n, server_ms)
    f[0] = 0
    f[1] = 0
    f[2] = 0
    f[3] = <unsigned char>(n - 4)
    f[4] = 0x91  # an array of one message
    return n


def pong_bytes(unsigned long long client_ms, unsigned long long server_ms):
    """The encoded PONG message as `pong_now` writes it (tests compare it with `encode_message`)."""
    cdef unsigned char f[32]
    cdef Py_ssize_t n = _pong_frame(f, client_ms, server_ms)
    return PyBytes_FromStringAndSize(<char *>f + 5, n - 5)


def pong_now(object server, object conn, long long client_ms):
    """See `pong_now_py`: the same decision (the core's, `Switchboard.pong_clear`), the same bytes written.
    The PONG is encoded here, as `quick_pong` encodes it (`now_ms(max(clock, 0))` rounds half to even, as
    `nearbyint` does in the default rounding mode); a clock that is not a finite float below 2**53 ms goes
    the core's way (`quick_pong`), which raises or answers as the reference does."""
    cdef unsigned char frame[32]
    cdef unsigned char head[5]
    cdef int n_iov
    cdef iovec iov[2]
    cdef Py_ssize_t blen, flen, sent
    cdef int fd, err
    cdef double t
    cdef object pong = None
    if conn.busy or conn.closed:
        return False
    sb = server.sb
    now = server.clock()
    if not sb.pong_clear(conn.cid, True):
        return False
    if type(now) is float and isfinite(<double>now) and <double>now * 1000.0 < <double>MAX_INT:
        t = <double>now
        if t < 0.0:
            t = 0.0
        flen = _pong_frame(frame, <unsigned long long>client_ms, <unsigned long long>nearbyint(t * 1000.0))
    else:
        pong = sb.quick_pong(conn.cid, Ping(client_ms), now, states_ok=True)
        if pong is None:
            return False
        flen = 0
    pacer = server.pacer
    if pacer is not None:
        pacer.woke()
    if len(conn.outbox):
        if pong is None:
            pong = PyBytes_FromStringAndSize(<char *>frame + 5, flen - 5)
        return server._pong_with_states(conn, pong)
    server.written += 1
    server.frames += 1
    fd = conn.fd
    if pong is None:
        iov[0].iov_base = <void *>frame
        iov[0].iov_len = flen
        n_iov = 1
    else:
        blen = len(<bytes>pong)
        head[0] = <unsigned char>(((blen + 1) >> 24) & 0xFF)
        head[1] = <unsigned char>(((blen + 1) >> 16) & 0xFF)
        head[2] = <unsigned char>(((blen + 1) >> 8) & 0xFF)
        head[3] = <unsigned char>((blen + 1) & 0xFF)
        head[4] = 0x91  # an array of one message
        iov[0].iov_base = <void *>head
        iov[0].iov_len = 5
        iov[1].iov_base = <void *><char *>(<bytes>pong)
        iov[1].iov_len = blen
        n_iov = 2
        flen = 5 + blen
    while True:
        sent = writev(fd, iov, n_iov)
        if sent >= 0:
            break
        err = errno
        if err != EINTR:
            break
    if sent < 0:
        if err == EAGAIN or err == EWOULDBLOCK:
            sent = 0
        else:
            scope = conn.scope
            if scope is not None:
                scope.cancel()  # peer gone: the handler closes and disconnects
            return True
    if sent < flen:
        if pong is None:
            conn.rest = PyBytes_FromStringAndSize(<char *>frame + sent, flen - sent)  # the writer task sends it
        else:
            conn.rest = ((<char *>head)[:5] + pong)[sent:]
        conn.busy = True
        conn.wake.set()
    return True
