"""Compiled (numba) helpers of the MCAP log. Internal: used by ``mcap_log`` and ``pipeline_log``.

* :func:`expand_records` turns the deferred ticks of a chunk buffer into MCAP
  Message records, each from a template and the JSON text of the tick's numbers
  (one ``orjson.dumps`` call on the main thread formats them all, shortest
  round-trip form), so no per-message Python runs.
* :func:`message_indexes` builds a chunk's MessageIndex records by scanning its
  Message records and computes its CRC-32; it runs in the writer thread and
  releases the GIL (every GIL hand-over between the writer thread and the busy
  pipeline loop costs two thread switches, so the writer makes as few as it can).
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


def crc32_tables() -> np.ndarray:
    """Slicing-by-8 tables of the CRC-32 of zlib (reflected, polynomial 0xEDB88320)."""
    t = np.zeros((8, 256), dtype=np.uint32)
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0xEDB88320 if c & 1 else c >> 1
        t[0, i] = c
    for i in range(256):
        c = int(t[0, i])
        for k in range(1, 8):
            c = int(t[0, c & 0xFF]) ^ (c >> 8)
            t[k, i] = c
    return t


@njit(cache=True, nogil=True)
def crc32(data, tables):  # pragma: no cover - compiled
    """zlib.crc32(data) (slicing by 8)."""
    crc = np.uint32(0xFFFFFFFF)
    n = len(data)
    i = 0
    while i + 8 <= n:
        a = crc ^ (
            np.uint32(data[i])
            | (np.uint32(data[i + 1]) << 8)
            | (np.uint32(data[i + 2]) << 16)
            | (np.uint32(data[i + 3]) << 24)
        )
        crc = (
            tables[7, a & 0xFF]
            ^ tables[6, (a >> 8) & 0xFF]
            ^ tables[5, (a >> 16) & 0xFF]
            ^ tables[4, a >> 24]
            ^ tables[3, data[i + 4]]
            ^ tables[2, data[i + 5]]
            ^ tables[1, data[i + 6]]
            ^ tables[0, data[i + 7]]
        )
        i += 8
    while i < n:
        crc = tables[0, (crc ^ data[i]) & 0xFF] ^ (crc >> 8)
        i += 1
    return crc ^ np.uint32(0xFFFFFFFF)


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


@njit(cache=True, inline="always")
def _fill(values, v0, v1, n_tokens, ops, r0, r1, pool, ns, out, pos):  # pragma: no cover
    # tokens of values[v0:v1]
    starts = np.empty(MAX_TOKENS, np.int64)
    ends = np.empty(MAX_TOKENS, np.int64)
    nt = 0
    start = -1
    for i in range(v0, v1):
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
    rec = 0
    sec = ns // 1_000_000_000
    nsec = ns - sec * 1_000_000_000
    for r in range(r0, r1):
        op = ops[r, 0]
        a = ops[r, 1]
        if op == OP_LITERAL:
            b = ops[r, 2]
            out[pos : pos + b] = pool[a : a + b]
            pos += b
        elif op == OP_TOKEN:
            for k in range(starts[a], ends[a]):
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


#: Opcode of a deferred tick inside a chunk buffer (not an MCAP opcode): u64 length,
#: u16 template, u64 log time, then the values text; :func:`expand_records` turns it
#: into the tick's Message records in the writer thread.
DEFERRED = 0xFF


@njit(cache=True, nogil=True)
def expand_records(buf, ops, bounds, pool, n_tokens, out):  # pragma: no cover - compiled
    """Copy the records of ``buf`` into ``out``, deferred ticks filled from their template.

    Template ``k`` is ``ops[bounds[k]:bounds[k + 1]]`` with ``n_tokens[k]`` tokens.
    Returns the length written, or -1 - (offset of a deferred tick that does not
    fit its template).
    """
    n = len(buf)
    pos = 0
    i = 0
    while i + 9 <= n:
        length = np.int64(0)
        for k in range(8):
            length |= np.int64(buf[i + 1 + k]) << (8 * k)
        if buf[i] == DEFERRED:
            tid = np.int64(buf[i + 9]) | (np.int64(buf[i + 10]) << 8)
            ns = np.int64(0)
            for k in range(8):
                ns |= np.int64(buf[i + 11 + k]) << (8 * k)
            got = _fill(
                buf,
                i + 19,
                i + 9 + length,
                n_tokens[tid],
                ops,
                bounds[tid],
                bounds[tid + 1],
                pool,
                ns,
                out,
                pos,
            )
            if got < 0:
                return -1 - i
            pos = got
        else:
            out[pos : pos + 9 + length] = buf[i : i + 9 + length]
            pos += 9 + length
        i += 9 + length
    return pos


@njit(cache=True, nogil=True)
def chunk_summary(rec, tables, index_start, out, ids, offsets, counts, times):  # pragma: no cover
    """:func:`message_indexes` and the CRC-32 of ``rec`` in one GIL-free call."""
    nch, length, m = message_indexes(rec, index_start, out, ids, offsets, counts, times)
    return nch, length, m, np.int64(crc32(rec, tables))


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
