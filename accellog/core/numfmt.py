"""CSV rows of float64 in '%.9g' text, vectorised: the bytes np.savetxt(fmt="%.9g", delimiter=",")
writes, ~3x faster than it (the integrate CSV holds 14.4 M rows of 7 values at 4 h).
Kept over the libraries (benchmarks/bench_export.py, 1 h of 1 kHz integrate rows): np.savetxt takes 3.0x
the CPU (8.4 s vs 2.8 s); pyarrow.csv.write_csv (3.1 s) writes shortest round-trip text, another file
(0.00023852234039306643 and 1.19e-7 for '%.9g''s 0.00023852234 and 1.19e-07; 1.6x the bytes).

Each value x is rounded to 9 significant digits N (1e8 <= N < 1e9) with decimal exponent X, from
y = x * 10^(8 - X) in float: one rounding, |y - exact| <= 2^-24 (y < 2^30), so rint(y) is the
correctly rounded N unless y lies within 1e-6 of a half-integer. Those values (about 2 in a
million), zeros, non-finite values and |8 - X| > 22 (10^k is then not an exact float) are formatted
by Python's '%.9g' itself; the others are laid out by C printf's %g rule (fixed for -4 <= X < 9, else exponential;
trailing zeros and a bare point dropped). tests/core/test_numfmt.py checks the bytes against '%.9g'.
"""

from __future__ import annotations

import numpy as np

_W = 17  # slots per value: a sign, at most 15 characters, the separator
_DOT, _ZERO, _MINUS, _PLUS, _E = (ord(c) for c in ".0-+e")


def _keep_table() -> np.ndarray:
    """(W * W, W) bool: row a * W + b keeps columns a..b of a value's slots."""
    col = np.arange(_W)
    a, b = np.divmod(np.arange(_W * _W), _W)
    return (col >= a[:, None]) & (col <= b[:, None])


_KEEP = _keep_table()


def _exponent(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N int64, X int64, sure bool) of |x| > 0 finite: 9 significant digits, exponent, rint exact."""
    a = np.abs(x)
    ex = np.floor(np.log10(a)).astype(np.int64)
    y = _scale(a, ex)
    off = np.flatnonzero((y >= 1e9) | (y < 1e8))  # log10 one off near a power of ten
    ex[off] += (y[off] >= 1e9).astype(np.int64) - (y[off] < 1e8)
    y[off] = _scale(a[off], ex[off])
    frac = y - np.floor(y)
    ok = (np.abs(ex - 8) <= 22) & (y >= 1e8) & (y < 1e9) & (np.abs(frac - 0.5) > 1e-6)
    n = np.rint(y).astype(np.int64)
    top = n >= 1_000_000_000  # 999999999.7 rounds up to 1.00000000e(X+1)
    n[top] = 100_000_000
    return n, ex + top, ok


_POW10 = 10.0 ** np.arange(23)  # exact floats


def _scale(a: np.ndarray, ex: np.ndarray) -> np.ndarray:
    """a * 10^(8 - ex) with one rounding (exact powers of ten up to 10^22; others: not ok)."""
    k = np.clip(8 - ex, -22, 22)
    p = _POW10[np.abs(k)]
    return np.where(k >= 0, a * p, a / p)


def _layout(n: np.ndarray, ex: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(m, 17) ASCII, first and last column of '%.9g' of values with digits n, exponent ex; the
    sign slot just before the first digit holds '-'. Fixed notation is right-aligned (the digits of
    n from the right, the point after F = 8 - ex of them, the stripped zeros drop off the right),
    exponential left-aligned from column 1."""
    m = n.size
    e = np.empty((10, m), np.uint8)  # e[r]: digit r from the right; e[9] the '0' of 0.xxx
    n = n.astype(np.uint32)
    for r in range(9):
        n, d = np.divmod(n, np.uint32(10))
        e[r] = d
    e += _ZERO
    e[9] = _ZERO
    tz = np.zeros(m, np.int8)  # trailing zeros of the 9 digits
    run = np.ones(m, bool)
    for r in range(8):
        run &= e[r] == _ZERO
        tz += run
    f = (8 - ex).astype(np.int8)  # fraction digits before stripping (ex >= -4 in fixed notation)
    width = f + np.maximum(ex + 1, 1).astype(np.int8)  # digits of the unstripped fixed text
    out = np.empty((_W, m), np.uint8)
    for r in range(16):
        ch = np.where(f < r, e[max(r - 1, 0)], e[r]) if r < 10 else np.full(m, _ZERO, np.uint8)
        ch[f == r] = _DOT
        ch[width < r] = _MINUS
        out[15 - r] = ch
    out = out.T
    first = 15 - width.astype(np.int64)
    last = 15 - np.minimum(tz, f).astype(np.int64) - (tz >= f)
    x = np.flatnonzero((ex < -4) | (ex >= 9))
    if x.size:
        out[x, 1:16], ln = _exponential(e[:, x].T, 9 - tz[x].astype(np.int64), ex[x])
        out[x, 0] = _MINUS
        first[x], last[x] = 1, ln
    return out, first, last


def _exponential(e: np.ndarray, s: np.ndarray, ex: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d.dddddddde+XX with trailing zeros dropped (e: the _layout digits from the right)."""
    m = s.size
    mm = np.where(s > 1, s + 1, 1)  # mantissa length
    ae = np.abs(ex)
    ne = np.where(ae >= 100, 3, 2)
    edig = [_ZERO + (ae // 100) % 10, _ZERO + (ae // 10) % 10, _ZERO + ae % 10]
    out = np.zeros((m, 15), np.uint8)
    for j in range(15):
        ch = e[:, 8 - min(max(j - 1, 0), 8)]
        ch = np.where((j == 1) & (s > 1), _DOT, ch)
        ch = np.where(j == mm, _E, ch)
        ch = np.where(j == mm + 1, np.where(ex < 0, _MINUS, _PLUS), ch)
        k = j - mm - 2 + (3 - ne)  # exponent digit 0..2
        out[:, j] = np.where(j >= mm + 2, np.choose(np.clip(k, 0, 2), edig), ch)
    return out, mm + 2 + ne


def format_rows(a: np.ndarray, sep: str = ",", rows_at_once: int = 4096) -> bytes:
    """np.savetxt(f, a, fmt="%.9g", delimiter=sep)'s bytes of a float (rows, cols) array, formatted
    rows_at_once rows at a time (the work arrays take ~100 bytes per value)."""
    a = np.asarray(a, float)
    if a.ndim != 2:
        raise ValueError(f"format_rows takes a 2-D array, not {a.ndim}-D")
    step = max(int(rows_at_once), 1)
    return b"".join(_rows(a[i : i + step], sep) for i in range(0, a.shape[0], step))


def _rows(a: np.ndarray, sep: str) -> bytes:
    """format_rows of one piece."""
    a = np.ascontiguousarray(a)
    rows, cols = a.shape
    x = a.ravel()
    neg = np.signbit(x)
    with np.errstate(all="ignore"):  # values not ok (0, inf, nan, ties) are formatted by Python
        n, ex, ok = _exponent(x)
    ok &= np.isfinite(x) & (x != 0)
    n[~ok], ex[~ok] = 100_000_000, 0
    out, first, last = _layout(n, ex)  # text in columns first..last, '-' just before it
    for j in np.flatnonzero(~ok):
        b = f"{float(x[j]):.9g}".encode()  # savetxt's "%.9g" % x: the same text
        neg[j] = b.startswith(b"-")
        b = b if neg[j] else b"-" + b  # '-' in column 0, the text from column 1
        out[j, : len(b)] = np.frombuffer(b, np.uint8)
        first[j], last[j] = 1, len(b) - 1
    seps = np.full((rows, cols), ord(sep), np.uint8)
    seps[:, -1] = ord("\n")
    out[np.arange(x.size), last + 1] = seps.ravel()
    return out[_KEEP[(first - neg) * _W + last + 1]].tobytes()
