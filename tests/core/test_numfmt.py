"""core.numfmt.format_rows writes the bytes np.savetxt(fmt="%.9g", delimiter=",") writes."""

import io

import numpy as np

from accellog.core.numfmt import format_rows


def _savetxt(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.savetxt(buf, a, delimiter=",", fmt="%.9g")
    return buf.getvalue()


def _check(x: np.ndarray, cols: int = 7) -> None:
    a = x[: x.size // cols * cols].reshape(-1, cols)
    got, want = format_rows(a), _savetxt(a)
    if got != want:  # name the first differing row, not two megabytes of text
        g, w = got.split(b"\n"), want.split(b"\n")
        i = next(i for i in range(len(w)) if i >= len(g) or g[i] != w[i])
        raise AssertionError(f"row {i}: {g[i] if i < len(g) else None!r} != {w[i]!r}")


def test_random_magnitudes_signs_and_every_exponent():
    rng = np.random.default_rng(1)
    _check(rng.normal(0, 1, 200_000) * 10.0 ** rng.integers(-40, 40, 200_000))


def test_values_at_the_rounding_edges():
    rng = np.random.default_rng(2)
    near = [1, -1, 1 + 1e-9, 1 - 1e-9, 0.9999999995, 9.9999999995, 9.999999994, 1.00000000049, 1.0000000005]
    _check(10.0 ** rng.integers(-25, 25, 50_000) * rng.choice(near, 50_000))
    # values with few digits (trailing zeros and a bare point dropped), exact halves of the 9th digit
    _check(np.concatenate([np.round(rng.normal(0, 1e4, 20_000), k) for k in range(10)]))
    _check(np.concatenate([(np.arange(1, 2001) + 0.5) * 10.0**k for k in range(-12, 12)]))


def test_zero_non_finite_and_extremes_take_pythons_text():
    x = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 5e-324, -5e-324, 2.2250738585072014e-308,
                  1.7976931348623157e308, 0.5, 1.5, 2.5, 0.125, 1e-5, 1e-4, -1e-4, 123456789.5,
                  999999999.5, 1e9, 1e8, 99999999.95, 0.00001234567895, 1e22, 1e23, 1e-15, 1e-14])  # fmt: skip
    _check(x, cols=1)
    _check(x[:25], cols=5)


def test_integrate_like_columns_and_one_row():
    rng = np.random.default_rng(3)
    n = 30_000
    t = 14_000.0 + np.arange(n) / 1000.0  # a 4 h session's stamps
    v = rng.normal(0, 1e-3, (n, 3)).cumsum(axis=0)
    a = np.column_stack([t, v, v.cumsum(axis=0) * 1e-3])
    a[0, 1:] = 0.0
    _check(a.ravel())
    _check(a[:1].ravel())
