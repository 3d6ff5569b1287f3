"""The model-gap fits' solvers: bounded least squares and a bounded simplex search from
scipy.optimize (imported when first used; ``pip install 'hdrd[gap]'``), and a closed-form
chi-squared tail. bench/gap_libraries.py compares them with hand-written ones (kept there)
and chi2_sf with scipy.stats: see docs/model-gap.md, "Libraries"."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from hdrd.analysis.gap.data import GapError

__all__ = ["chi2_sf", "least_squares_bounded", "minimize_simplex"]

FloatArray = npt.NDArray[np.float64]


def _scipy_optimize() -> Any:
    try:
        import scipy.optimize
    except ImportError:  # pragma: no cover - the gap extra installs it
        raise GapError(
            "hdrd gap needs scipy for its fits: pip install 'hdrd[gap]' (or pip install scipy)"
        ) from None
    return scipy.optimize


def least_squares_bounded(
    fun: Callable[[FloatArray], FloatArray],
    x0: FloatArray,
    steps: FloatArray,
    lower: FloatArray,
    upper: FloatArray,
) -> FloatArray:
    """Minimise |fun(x)|**2 within [lower, upper] (scipy's trust-region reflective least
    squares, forward-difference Jacobian with absolute steps ``steps`` near 0; a start within
    1e-6 steps of zero starts at zero)."""
    lo = np.asarray(lower, dtype=np.float64)
    hi = np.asarray(upper, dtype=np.float64)
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    x = np.clip(np.asarray(x0, dtype=np.float64), lo + 1e-9 * span, hi - 1e-9 * span)
    # The first trust region scales with the start: one nearly but not exactly zero (a bias
    # pinned at a stop) would give it no room to move; exactly zero gives it a unit one.
    x = np.where(np.abs(x) < 1e-6 * np.asarray(steps), 0.0, x)
    res = _scipy_optimize().least_squares(
        fun, x, bounds=(lo, hi), x_scale="jac", diff_step=np.asarray(steps), method="trf"
    )
    return np.asarray(res.x, dtype=np.float64)


def minimize_simplex(
    f: Callable[[FloatArray], float], x0: FloatArray, lower: FloatArray, upper: FloatArray
) -> FloatArray:
    """Minimise f within [lower, upper] by scipy's Nelder-Mead from its own initial simplex
    (5 % of each coordinate; tolerances 1e-4 in x and f: a log-likelihood needs no finer)."""
    lo = np.asarray(lower, dtype=np.float64)
    hi = np.asarray(upper, dtype=np.float64)
    x = np.clip(np.asarray(x0, dtype=np.float64), lo, hi)
    res = _scipy_optimize().minimize(
        f,
        x,
        method="Nelder-Mead",
        bounds=list(zip(lo, hi)),
        options={"xatol": 1e-4, "fatol": 1e-4},
    )
    return np.asarray(res.x, dtype=np.float64)


def chi2_sf(x: float, k: int) -> float:
    """P(chi-squared with k degrees of freedom > x), k a positive integer (closed forms)."""
    if x <= 0:
        return 1.0
    h = 0.5 * x
    if k % 2 == 0:
        term, s = 1.0, 1.0
        for i in range(1, k // 2):
            term *= h / i
            s += term
        return float(min(1.0, math.exp(-h) * s))
    s = math.erfc(math.sqrt(h))
    for i in range((k - 1) // 2):
        s += math.exp(-h + (i + 0.5) * math.log(h) - math.lgamma(i + 1.5))
    return float(min(1.0, s))
