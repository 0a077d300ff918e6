"""Compiled parsers for the plain cases of the text formats (Numba; imported on first use).

``parse_off(buf)``, ``parse_obj(buf)`` and ``parse_rows(buf, ...)`` read the bytes of a file in
one pass and return the arrays trimesh's loader (OFF, OBJ) or NumPy's ``loadtxt`` (XYZ, SEG) would
give, or a status saying the file is not a plain case, in which case the caller reads it as before.

Why not a library: trimesh's text loaders split every line into Python strings and convert them
with ``np.array(..., float)``: 80-110 ms for a 30k-face OFF, as much as libigl's whole distance step
on the same mesh. ``np.array(text.split(), float)`` over the whole file still took 45 ms (split 14,
vertices 16, faces 14), ``np.fromstring(text, sep=' ')`` 80 ms, pandas is not a dependency, and
``np.loadtxt`` cannot read OFF's two blocks of different widths. One pass over the bytes here takes
about 2 ms.

Plain case: ASCII only (bytes ``0-9 + - . e E``, space, tab, ``\\n``, ``\\r\\n`` and the letters of
the keywords), no comments, exactly three coordinates a vertex and three corners a face, every
index in range. Anything else (a polygon, colours after the coordinates, ``nan``, a ``#``, a lone
``\\r``, a count that does not match) returns ``FALLBACK`` and the file goes through the old path,
so every check and every message of the readers stays what it was.

Numbers are correctly rounded, so they equal Python's ``float`` (which trimesh and NumPy use) to the
last bit: a decimal with at most 18 significant digits ``m`` and a power of ten ``10^k``,
``|k| <= 22``, ``m <= 2^53``, is one IEEE multiplication or division of two exact doubles
(Clinger's fast path, "How to read floating point numbers accurately", PLDI 1990). Any other number
(17-digit ``%.17g`` output, huge exponents) is left to Python's ``float``: its place comes back in
``slow`` and the caller converts it.
"""

import numba
import numpy as np

OK = 0
FALLBACK = 1

_SPACE, _TAB, _LF, _CR = 32, 9, 10, 13
_ZERO, _NINE, _PLUS, _MINUS, _DOT = 48, 57, 43, 45, 46
_TWO53 = 9007199254740992

# 10^0 .. 10^22 are exact doubles
_POW10 = np.array([10.0**k for k in range(23)], dtype=np.float64)


@numba.njit(cache=True, nogil=True, inline="always")
def _blank(c):
    return c == _SPACE or c == _TAB


@numba.njit(cache=True, nogil=True)
def _skip_blank(buf, i, n):
    while i < n and _blank(buf[i]):
        i += 1
    return i


@numba.njit(cache=True, nogil=True)
def _skip_space(buf, i, n):
    """Past blanks and line ends (``\\n`` or ``\\r\\n``); -1 on a lone ``\\r``."""
    while i < n:
        c = buf[i]
        if c == _SPACE or c == _TAB or c == _LF:
            i += 1
        elif c == _CR:
            if i + 1 < n and buf[i + 1] == _LF:
                i += 2
            else:
                return -1
        else:
            break
    return i


@numba.njit(cache=True, nogil=True)
def _end_of_line(buf, i, n):
    """Past the blanks and the line end at ``i`` (or at the end of the data); -1 when something else is there."""
    i = _skip_blank(buf, i, n)
    if i == n:
        return n
    if buf[i] == _LF:
        return i + 1
    if buf[i] == _CR and i + 1 < n and buf[i + 1] == _LF:
        return i + 2
    return -1


@numba.njit(cache=True, nogil=True, inline="always")
def _token_end(buf, i, n):
    return i == n or _blank(buf[i]) or buf[i] == _LF or buf[i] == _CR


@numba.njit(cache=True, nogil=True)
def _float(buf, i, n, pow10):
    """(value, next index, status) of the number at ``i``: status 0 parsed, 1 valid but left to
    Python's float (value NaN), -1 not a plain number."""
    neg = False
    if i < n and (buf[i] == _PLUS or buf[i] == _MINUS):
        neg = buf[i] == _MINUS
        i += 1
    m = 0
    digits = 0  # significant digits kept in m
    exp10 = 0
    seen = False
    slow = False
    while i < n and _ZERO <= buf[i] <= _NINE:
        seen = True
        d = buf[i] - _ZERO
        if m > 0 or d > 0:
            if digits < 18:
                m = m * 10 + d
                digits += 1
            else:
                slow = True
        i += 1
    if i < n and buf[i] == _DOT:
        i += 1
        while i < n and _ZERO <= buf[i] <= _NINE:
            seen = True
            d = buf[i] - _ZERO
            if m > 0 or d > 0:
                if digits < 18:
                    m = m * 10 + d
                    digits += 1
                    exp10 -= 1
                elif d > 0:
                    slow = True
            else:
                exp10 -= 1
            i += 1
    if not seen:
        return 0.0, i, -1
    if i < n and (buf[i] == 101 or buf[i] == 69):  # e E
        i += 1
        eneg = False
        if i < n and (buf[i] == _PLUS or buf[i] == _MINUS):
            eneg = buf[i] == _MINUS
            i += 1
        e = 0
        edigits = 0
        while i < n and _ZERO <= buf[i] <= _NINE:
            if e < 100000:
                e = e * 10 + (buf[i] - _ZERO)
            edigits += 1
            i += 1
        if edigits == 0:
            return 0.0, i, -1
        exp10 += -e if eneg else e
    if not _token_end(buf, i, n):
        return 0.0, i, -1
    if m == 0 and not slow:
        value = 0.0
    elif slow or m > _TWO53 or exp10 < -22 or exp10 > 22:
        return np.nan, i, 1
    elif exp10 >= 0:
        value = float(m) * pow10[exp10]
    else:
        value = float(m) / pow10[-exp10]
    return (-value if neg else value), i, 0


@numba.njit(cache=True, nogil=True, inline="always")  # inlined: a call per number cost ~7% of a read
def _number(buf, i, n, pow10, slow, nslow, index):
    """:func:`_float` at ``i``, and a number it leaves to Python recorded as the row ``(index, start,
    end)`` of ``slow`` (``index``: the number's flat index in the output). Returns ``(value, i,
    nslow, status)``; status < 0: not a plain number."""
    start = i
    value, i, status = _float(buf, i, n, pow10)
    if status == 1:
        slow[nslow, 0] = index
        slow[nslow, 1] = start
        slow[nslow, 2] = i
        nslow += 1
    return value, i, nslow, status


@numba.njit(cache=True, nogil=True)
def _uint(buf, i, n):
    """(value, next index) of the unsigned integer at ``i``; value -1 when it is not one (or has
    more than 18 digits)."""
    start = i
    v = 0
    while i < n and _ZERO <= buf[i] <= _NINE:
        v = v * 10 + (buf[i] - _ZERO)
        i += 1
    if i == start or i - start > 18 or not _token_end(buf, i, n):
        return -1, i
    return v, i


@numba.njit(cache=True, nogil=True)
def parse_off(buf):
    """(status, vertices (nv, 3) float64, faces (nf, 3) int64, slow (k, 3) int64) of OFF bytes.

    ``slow`` holds (flat vertex index, start, end byte offsets) of the numbers left to Python's float.
    """
    pow10 = _POW10
    n = len(buf)
    empty_v = np.zeros((0, 3), np.float64)
    empty_f = np.zeros((0, 3), np.int64)
    empty_s = np.zeros((0, 3), np.int64)
    i = _skip_space(buf, 0, n)
    if i < 0 or i + 3 > n or buf[i] != 79 or buf[i + 1] != 70 or buf[i + 2] != 70:  # OFF
        return FALLBACK, empty_v, empty_f, empty_s
    i += 3
    if i == n or not (_blank(buf[i]) or buf[i] == _LF or buf[i] == _CR):
        return FALLBACK, empty_v, empty_f, empty_s
    i = _skip_space(buf, i, n)
    if i < 0:
        return FALLBACK, empty_v, empty_f, empty_s
    # the counts line: two or more integers (vertices, faces, edges)
    nv, i = _uint(buf, i, n)
    if nv < 0:
        return FALLBACK, empty_v, empty_f, empty_s
    i = _skip_blank(buf, i, n)
    nf, i = _uint(buf, i, n)
    if nf < 0:
        return FALLBACK, empty_v, empty_f, empty_s
    while True:
        j = _end_of_line(buf, i, n)
        if j >= 0:
            i = j
            break
        i = _skip_blank(buf, i, n)
        extra, i = _uint(buf, i, n)
        if extra < 0:
            return FALLBACK, empty_v, empty_f, empty_s
    # each vertex line takes at least 6 bytes, each face line 8: a count beyond that is not plain
    if nv == 0 or nf == 0 or nv > n // 6 + 1 or nf > n // 8 + 1:
        return FALLBACK, empty_v, empty_f, empty_s
    vertices = np.empty((nv, 3), np.float64)
    slow = np.empty((3 * nv, 3), np.int64)
    nslow = 0
    for v in range(nv):
        i = _skip_space(buf, i, n)
        if i < 0:
            return FALLBACK, empty_v, empty_f, empty_s
        for k in range(3):
            if k:
                i = _skip_blank(buf, i, n)
            value, i, nslow, status = _number(buf, i, n, pow10, slow, nslow, 3 * v + k)
            if status < 0:
                return FALLBACK, empty_v, empty_f, empty_s
            vertices[v, k] = value
        i = _end_of_line(buf, i, n)
        if i < 0:
            return FALLBACK, empty_v, empty_f, empty_s
    faces = np.empty((nf, 3), np.int64)
    for f in range(nf):
        i = _skip_space(buf, i, n)
        if i < 0:
            return FALLBACK, empty_v, empty_f, empty_s
        count, i = _uint(buf, i, n)
        if count != 3:
            return FALLBACK, empty_v, empty_f, empty_s
        for k in range(3):
            i = _skip_blank(buf, i, n)
            index, i = _uint(buf, i, n)
            if index < 0 or index >= nv:
                return FALLBACK, empty_v, empty_f, empty_s
            faces[f, k] = index
        i = _end_of_line(buf, i, n)
        if i < 0:
            return FALLBACK, empty_v, empty_f, empty_s
    i = _skip_space(buf, i, n)
    if i != n:  # anything after the faces
        return FALLBACK, empty_v, empty_f, empty_s
    return OK, vertices, faces, slow[:nslow].copy()


@numba.njit(cache=True, nogil=True)
def parse_obj(buf):
    """(status, vertices (nv, 3) float64, faces (nf, 3) int64, slow (k, 3) int64) of OBJ bytes.

    Plain case: ``v x y z`` lines and ``f a b c`` lines whose corners are positive vertex numbers,
    each optionally followed by ``/texture`` and ``/normal`` numbers (ignored); lines whose first
    word is neither ``v`` nor ``f`` (``vt``, ``vn``, ``g``, ``usemtl``, comments...) are skipped,
    as :func:`primkit.io.formats._obj_geometry_only` skips them.
    """
    pow10 = _POW10
    n = len(buf)
    empty_v = np.zeros((0, 3), np.float64)
    empty_f = np.zeros((0, 3), np.int64)
    empty_s = np.zeros((0, 3), np.int64)
    # a first pass counts the v and f lines, so that the arrays are allocated once
    nv = 0
    nf = 0
    i = 0
    while i < n:
        i = _skip_blank(buf, i, n)
        if i + 1 < n and (buf[i] == 118 or buf[i] == 102) and _blank(buf[i + 1]):  # 'v ' 'f '
            if buf[i] == 118:
                nv += 1
            else:
                nf += 1
        while i < n and buf[i] != _LF:
            i += 1
        i += 1
    if nv == 0 or nf == 0:
        return FALLBACK, empty_v, empty_f, empty_s
    vertices = np.empty((nv, 3), np.float64)
    faces = np.empty((nf, 3), np.int64)
    slow = np.empty((3 * nv, 3), np.int64)
    nslow = 0
    v = 0
    f = 0
    i = 0
    while i < n:
        i = _skip_blank(buf, i, n)
        if i + 1 < n and buf[i] == 118 and _blank(buf[i + 1]):
            i += 1
            for k in range(3):
                i = _skip_blank(buf, i, n)
                value, i, nslow, status = _number(buf, i, n, pow10, slow, nslow, 3 * v + k)
                if status < 0:
                    return FALLBACK, empty_v, empty_f, empty_s
                vertices[v, k] = value
            v += 1
            i = _end_of_line(buf, i, n)
            if i < 0:
                return FALLBACK, empty_v, empty_f, empty_s
        elif i + 1 < n and buf[i] == 102 and _blank(buf[i + 1]):
            i += 1
            for k in range(3):
                i = _skip_blank(buf, i, n)
                start = i
                index = 0
                while i < n and _ZERO <= buf[i] <= _NINE and i - start < 18:
                    index = index * 10 + (buf[i] - _ZERO)
                    i += 1
                if i == start or index < 1:
                    return FALLBACK, empty_v, empty_f, empty_s
                # '/texture/normal' after the vertex number: digits and slashes only
                while i < n and (buf[i] == 47 or _ZERO <= buf[i] <= _NINE):
                    i += 1
                if not _token_end(buf, i, n):
                    return FALLBACK, empty_v, empty_f, empty_s
                faces[f, k] = index - 1
            f += 1
            i = _end_of_line(buf, i, n)
            if i < 0:
                return FALLBACK, empty_v, empty_f, empty_s
        else:
            # another kind of line: skipped whole, but only plain ASCII text (no lone '\r')
            while i < n and buf[i] != _LF:
                c = buf[i]
                if c > 126 or (c < 32 and c != _TAB and not (c == _CR and i + 1 < n and buf[i + 1] == _LF)):
                    return FALLBACK, empty_v, empty_f, empty_s
                i += 1
            i += 1
    for f in range(nf):
        for k in range(3):
            if faces[f, k] >= nv:
                return FALLBACK, empty_v, empty_f, empty_s
    return OK, vertices, faces, slow[:nslow].copy()


@numba.njit(cache=True, nogil=True)
def parse_rows(buf):
    """(status, values (rows, cols) float64, slow (k, 3) int64) of whitespace-separated rows of
    numbers (an ``.xyz`` cloud): every row as many columns as the first, blank lines skipped.
    ``slow`` holds (flat index, start, end byte offsets) of the numbers left to Python's float."""
    pow10 = _POW10
    n = len(buf)
    empty = np.zeros((0, 0), np.float64)
    empty_s = np.zeros((0, 3), np.int64)
    rows, cols = _count_rows(buf, n)
    if rows <= 0:
        return FALLBACK, empty, empty_s
    values = np.empty((rows, cols), np.float64)
    slow = np.empty((rows * cols, 3), np.int64)
    nslow = 0
    i = 0
    for r in range(rows):
        i = _skip_space(buf, i, n)
        for k in range(cols):
            if k:
                i = _skip_blank(buf, i, n)
            value, i, nslow, status = _number(buf, i, n, pow10, slow, nslow, r * cols + k)
            if status < 0:
                return FALLBACK, empty, empty_s
            values[r, k] = value
        i = _end_of_line(buf, i, n)
        if i < 0:
            return FALLBACK, empty, empty_s
    return OK, values, slow[:nslow].copy()


@numba.njit(cache=True, nogil=True)
def parse_labels(buf):
    """(status, labels (rows,) int64) of one integer (``-``, then at most 18 digits) per line, blank
    lines skipped (an ``.seg`` file)."""
    n = len(buf)
    empty = np.zeros(0, np.int64)
    rows, cols = _count_rows(buf, n)
    if rows <= 0 or cols != 1:
        return FALLBACK, empty
    labels = np.empty(rows, np.int64)
    i = 0
    for r in range(rows):
        i = _skip_space(buf, i, n)
        neg = i < n and buf[i] == _MINUS
        if neg:
            i += 1
        value, i = _uint(buf, i, n)
        if value < 0:
            return FALLBACK, empty
        labels[r] = -value if neg else value
        i = _end_of_line(buf, i, n)
        if i < 0:
            return FALLBACK, empty
    return OK, labels


@numba.njit(cache=True, nogil=True)
def _count_rows(buf, n):
    """(rows, columns of the first row) of whitespace-separated text; rows -1 when a row has
    another number of columns or a lone ``\\r`` is met."""
    rows = 0
    cols = -1
    i = 0
    while i < n:
        i = _skip_space(buf, i, n)
        if i < 0:
            return -1, 0
        if i == n:
            break
        count = 0
        while True:
            while i < n and not _token_end(buf, i, n):
                i += 1
            count += 1
            j = _end_of_line(buf, i, n)
            if j >= 0:
                i = j
                break
            i = _skip_blank(buf, i, n)
            if i < n and buf[i] == _CR:  # a lone '\\r'
                return -1, 0
        if cols < 0:
            cols = count
        elif count != cols:
            return -1, 0
        rows += 1
    return rows, cols


@numba.njit(cache=True, nogil=True)
def gather_tokens(buf, slow):
    """The bytes of the numbers at ``slow`` ((k, 3): flat index, start, end), one space after each:
    one string for Python to split and convert at once."""
    total = 0
    for r in range(len(slow)):
        total += slow[r, 2] - slow[r, 1] + 1
    out = np.empty(total, np.uint8)
    j = 0
    for r in range(len(slow)):
        for i in range(slow[r, 1], slow[r, 2]):
            out[j] = buf[i]
            j += 1
        out[j] = _SPACE
        j += 1
    return out
