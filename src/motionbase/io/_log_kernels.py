"""Compiled (numba) helpers of the MCAP log. Internal: used by ``mcap_log`` and ``pipeline_log``.

* :func:`fill_template` writes one pipeline tick's MCAP Message records from a
  template and the JSON text of the tick's numbers (one ``orjson.dumps`` call
  formats them all, shortest round-trip form), so no per-message Python runs.
* :func:`message_indexes` builds a chunk's MessageIndex records by scanning its
  Message records; it runs in the writer thread and releases the GIL.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# template operations: rows (op, a, b) of an int64 array
OP_LITERAL = 0  # copy pool[a : a + b]
OP_TOKEN = 1  # copy number token a of the values text
OP_BEGIN = 2  # start a Message record on channel a (header written, length filled at OP_END)
OP_END = 3
OP_SEC = 4  # the decimal integer ns // 1e9
OP_NSEC = 5  # the decimal integer ns % 1e9

MAX_TOKENS = 128


@njit(cache=True, inline="always")
def _put_u64(out, pos, value):  # pragma: no cover - compiled
    for k in range(8):
        out[pos + k] = (value >> (8 * k)) & 0xFF


@njit(cache=True, inline="always")
def _put_int(out, pos, value):  # pragma: no cover - compiled
    # decimal digits of a non-negative integer; returns the new position
    if value == 0:
        out[pos] = 48
        return pos + 1
    n = 0
    v = value
    while v > 0:
        n += 1
        v //= 10
    v = value
    for k in range(n - 1, -1, -1):
        out[pos + k] = 48 + v % 10
        v //= 10
    return pos + n


@njit(cache=True)
def fill_template(values, n_tokens, ops, pool, ns, out):  # pragma: no cover - compiled
    """Message records of one tick into ``out``; returns their length, or -1.

    ``values`` is the JSON text of the tick's values (nested arrays of numbers,
    booleans and plain strings); its tokens, split at ``[``, ``]`` and ``,``, are
    inserted where the template says. -1 (nothing usable written) when the
    token count is not ``n_tokens`` or a token is ``null`` (a NaN or an
    infinity: the caller takes the general path).
    """
    starts = np.empty(MAX_TOKENS, np.int64)
    ends = np.empty(MAX_TOKENS, np.int64)
    nt = 0
    n = len(values)
    start = -1
    for i in range(n):
        c = values[i]
        if c == 44 or c == 93 or c == 91:  # , ] [
            if start >= 0:
                if nt == MAX_TOKENS:
                    return -1
                starts[nt] = start
                ends[nt] = i
                nt += 1
                start = -1
        elif start < 0:
            if c == 110:  # n(ull): a NaN or an infinity
                return -1
            start = i
    if start >= 0 or nt != n_tokens:
        return -1
    pos = 0
    rec = 0
    sec = ns // 1_000_000_000
    nsec = ns - sec * 1_000_000_000
    for r in range(ops.shape[0]):
        op = ops[r, 0]
        a = ops[r, 1]
        if op == OP_LITERAL:
            b = ops[r, 2]
            out[pos : pos + b] = pool[a : a + b]
            pos += b
        elif op == OP_TOKEN:
            s = starts[a]
            e = ends[a]
            for k in range(s, e):
                out[pos] = values[k]
                pos += 1
        elif op == OP_BEGIN:
            rec = pos
            out[pos] = 0x05
            # length at OP_END; channel u16, sequence u32 = 0, log and publish time u64
            out[pos + 9] = a & 0xFF
            out[pos + 10] = (a >> 8) & 0xFF
            for k in range(4):
                out[pos + 11 + k] = 0
            _put_u64(out, pos + 15, ns)
            _put_u64(out, pos + 23, ns)
            pos += 31
        elif op == OP_END:
            _put_u64(out, rec + 1, pos - rec - 9)
        elif op == OP_SEC:
            pos = _put_int(out, pos, sec)
        else:
            pos = _put_int(out, pos, nsec)
    return pos


@njit(cache=True, nogil=True)
def message_indexes(rec, index_start, out, ids, offsets, counts, times):  # pragma: no cover
    """MessageIndex records of a chunk whose uncompressed records are ``rec``.

    Channels in the order of their first message; per channel, (log_time, offset)
    pairs in record order. Writes the records into ``out`` and, per channel,
    its id, the file offset of its index record (``index_start`` + position)
    and its message count into ``ids``, ``offsets``, ``counts`` (room for 65536);
    ``times`` gets the chunk's (min, max) log time. Returns
    (channels, bytes written, messages).
    """
    n = len(rec)
    nmax = n // 31 + 1
    cid = np.empty(nmax, np.int64)
    tim = np.empty(nmax, np.int64)
    off = np.empty(nmax, np.int64)
    slot = np.full(65536, -1, np.int64)
    nch = 0
    m = 0
    pos = 0
    tmin = np.int64(0)
    tmax = np.int64(0)
    while pos + 9 <= n:
        length = np.int64(0)
        for k in range(8):
            length |= np.int64(rec[pos + 1 + k]) << (8 * k)
        if rec[pos] == 0x05:
            c = np.int64(rec[pos + 9]) | (np.int64(rec[pos + 10]) << 8)
            t = np.int64(0)
            for k in range(8):
                t |= np.int64(rec[pos + 15 + k]) << (8 * k)
            cid[m] = c
            tim[m] = t
            off[m] = pos
            if m == 0 or t < tmin:
                tmin = t
            if m == 0 or t > tmax:
                tmax = t
            m += 1
            if slot[c] < 0:
                slot[c] = nch
                ids[nch] = c
                counts[nch] = 0
                nch += 1
            counts[slot[c]] += 1
        pos += 9 + length
    times[0] = tmin
    times[1] = tmax
    # one MessageIndex record per channel: opcode, length, channel, body length, pairs
    p = 0
    for s in range(nch):
        c = ids[s]
        body = 16 * counts[s]
        offsets[s] = index_start + p
        out[p] = 0x07  # MessageIndex opcode
        _put_u64(out, p + 1, 6 + body)
        out[p + 9] = c & 0xFF
        out[p + 10] = (c >> 8) & 0xFF
        for k in range(4):
            out[p + 11 + k] = (body >> (8 * k)) & 0xFF
        p += 15
        for j in range(m):
            if cid[j] == c:
                _put_u64(out, p, tim[j])
                _put_u64(out, p + 8, off[j])
                p += 16
    return nch, p, m
