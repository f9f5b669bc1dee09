"""Short ``repr()`` for the objects a notebook shows: one line of what matters (well under 1 kB)
instead of a dataclass's dump of every array. IPython and Jupyter print ``repr()`` for a class that
defines it, so no ``_repr_pretty_`` is needed; a result with parameters adds ``_repr_html_``, a
table of name, value and 1-sigma (``param_table_html``).
"""

from __future__ import annotations

import html
from collections.abc import Iterable, Sequence

import numpy as np


def short_repr(name: str, parts: Iterable[object]) -> str:
    """'<name: part, part, ...>' without the empty parts."""
    return f"<{name}: " + ", ".join(str(p) for p in parts if p not in (None, "")) + ">"


def fit_text(model: str, n_params: int, chi2_dof: float | None, rms_g: float | None) -> str:
    """'model3 (12 params), chi2/dof 1.17, rms 0.157 mg' (the statistics when known)."""
    stats = (
        "" if chi2_dof is None or rms_g is None else f", chi2/dof {chi2_dof:.3g}, rms {rms_g * 1e3:.3g} mg"
    )
    return f"{model} ({n_params} params){stats}"


def names_text(names: Sequence[str], limit: int = 6) -> str:
    """The first ``limit`` names, then how many more: '+x, -x, ... (+18 more)'."""
    more = f" (+{len(names) - limit} more)" if len(names) > limit else ""
    return ", ".join(names[:limit]) + more


def param_table_html(
    title: str, names: Sequence[str], units: Sequence[str], values: np.ndarray, sigma: np.ndarray
) -> str:
    """An HTML table of parameters: name, value +- 1 sigma, unit (values printed with 4 significant
    digits, sigma with 2)."""
    rows = "".join(
        f"<tr><td>{html.escape(n)}</td><td>{v:.4g}</td><td>&plusmn; {s:.2g}</td><td>{html.escape(u)}</td></tr>"
        for n, u, v, s in zip(names, units, values, sigma, strict=True)
    )
    head = "<tr><th>parameter</th><th>value</th><th>1&sigma;</th><th>unit</th></tr>"
    return f"<table><caption>{html.escape(title)}</caption>{head}{rows}</table>"
