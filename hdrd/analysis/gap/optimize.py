"""Small optimisers and a chi-squared tail (numpy only) for the model-gap fits."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

__all__ = ["chi2_sf", "levenberg_marquardt", "nelder_mead"]

FloatArray = npt.NDArray[np.float64]


def levenberg_marquardt(
    fun: Callable[[FloatArray], FloatArray], x0: FloatArray, h: FloatArray, max_iter: int = 40
) -> FloatArray:
    """Minimise |fun(x)|**2 from x0 (forward-difference Jacobian with steps h)."""
    x = np.array(x0, dtype=np.float64)
    r = fun(x)
    cost = float(np.dot(r, r))
    lam = 1e-4
    for _ in range(max_iter):
        jac = np.empty((r.shape[0], x.shape[0]))
        for j in range(x.shape[0]):
            xp = x.copy()
            xp[j] += h[j]
            jac[:, j] = (fun(xp) - r) / h[j]
        # A parameter with no effect here (e.g. held at a bound) is left where it is: solving
        # for it would take round-off for a direction.
        dg = np.diag(jac.T @ jac).copy()
        act = dg > 1e-14 * max(float(dg.max()), 1e-300)
        if not act.any():
            break
        ja = jac[:, act]
        g = ja.T @ r
        a = ja.T @ ja
        accepted = False
        for _ in range(10):
            step = np.zeros_like(x)
            try:
                step[act] = -np.linalg.solve(a + lam * np.diag(dg[act]), g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            xn = x + step
            rn = fun(xn)
            cn = float(np.dot(rn, rn))
            if np.isfinite(cn) and cn <= cost:
                accepted = True
                done = cost - cn <= 1e-10 * max(cost, 1e-300)
                x, r, cost = xn, rn, cn
                lam = max(lam / 5.0, 1e-12)
                break
            lam *= 10.0
        if not accepted or done:
            break
    return x


def nelder_mead(
    f: Callable[[FloatArray], float], x0: FloatArray, scale: float = 0.5, iters: int = 80
) -> FloatArray:
    """Minimise f from x0 (unconstrained; a small simplex method, enough for 1-3 parameters)."""
    n = x0.shape[0]
    pts = [np.array(x0, dtype=np.float64)]
    for i in range(n):
        p = pts[0].copy()
        p[i] += scale
        pts.append(p)
    vals = [f(p) for p in pts]
    for _ in range(iters):
        order = np.argsort(vals)
        pts = [pts[i] for i in order]
        vals = [vals[i] for i in order]
        if abs(vals[-1] - vals[0]) < 1e-6 and np.max(np.abs(np.array(pts) - pts[0])) < 1e-4:
            break
        c = np.mean(pts[:-1], axis=0)
        xr = c + (c - pts[-1])
        fr = f(xr)
        if fr < vals[0]:
            xe = c + 2.0 * (c - pts[-1])
            fe = f(xe)
            pts[-1], vals[-1] = (xe, fe) if fe < fr else (xr, fr)
        elif fr < vals[-2]:
            pts[-1], vals[-1] = xr, fr
        else:
            xc = c + 0.5 * (pts[-1] - c)
            fc = f(xc)
            if fc < vals[-1]:
                pts[-1], vals[-1] = xc, fc
            else:
                for i in range(1, n + 1):
                    pts[i] = pts[0] + 0.5 * (pts[i] - pts[0])
                    vals[i] = f(pts[i])
    return pts[int(np.argmin(vals))]


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
