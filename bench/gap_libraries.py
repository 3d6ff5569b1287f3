#!/usr/bin/env python3
"""Model gap: our small optimisers, chi-squared tail and Allan deviation against scipy and
allantools, on the problems ``hdrd gap`` solves.

    python bench/gap_libraries.py [--no-write]

Takes about 3 minutes. Needs scipy and allantools (``pip install scipy allantools``).

1. Noise maximum likelihood (the Kalman-whitened block likelihood, parameters on a log
   scale): a hand-written Nelder-Mead (below, what hdrd gap used before) against
   scipy.optimize.minimize Nelder-Mead (what it uses now), Powell and L-BFGS-B (bounded), from
   the same start: best negative log-likelihood, function evaluations, time.
2. Deterministic least squares (the whitened block residual, each evaluation runs the
   simulator's effect code over the log): a hand-written Levenberg-Marquardt (below, used
   before) against scipy.optimize.least_squares (trf, bounds; used now): cost, evaluations,
   time, and a problem whose optimum lies beyond a bound.
3. chi2_sf against scipy.stats.chi2.sf: largest relative difference, time per call, and the
   import time scipy.stats adds to ``hdrd gap``.
4. Allan deviation (overlapping) against allantools.oadev, and on a log with gaps against
   allantools.gradev: largest relative difference and time.

Writes its section of bench/RESULTS.md (Model gap).
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
from _common import machine_line, write_section

from hdrd.analysis.gap.data import GapData, prepare
from hdrd.analysis.gap.fit import Fitter, with_params
from hdrd.analysis.gap.noise import Noise, Whitener, allan_deviation_masked
from hdrd.analysis.gap.optimize import chi2_sf, least_squares_bounded, minimize_simplex
from hdrd.io.files.drivelog import DriveLog
from hdrd.sim import DEFAULT_START_MODEL, simulate_drive
from hdrd.sim.effects import (
    Bandwidth,
    BiasInstability,
    RateRandomWalk,
    ScaleFactor,
    TemperatureBias,
    TimeOffset,
    WarmupTransient,
)
from hdrd.sim.gyro import GyroModel
from tests.gap_standins import imu_log, phone_log

Row = dict[str, Any]
FloatArray = np.ndarray


# -- the hand-written optimisers hdrd gap used before it took scipy's (the reference here) ----


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
    f: Callable[[FloatArray], float],
    x0: FloatArray,
    scale: float = 0.5,
    iters: int = 80,
    ftol: float = 1e-4,
    xtol: float = 1e-4,
) -> FloatArray:
    """Minimise f from x0 (unconstrained; a small simplex method, enough for 1-3 parameters).
    Stops when the simplex's values differ by less than ``ftol`` and its points by less than
    ``xtol`` (scipy's default tolerances; a log-likelihood needs no finer)."""
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
        if abs(vals[-1] - vals[0]) < ftol and np.max(np.abs(np.array(pts) - pts[0])) < xtol:
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


class Counted:
    """A function that counts its calls."""

    def __init__(self, fn: Callable[..., Any]) -> None:
        self.fn, self.n = fn, 0

    def __call__(self, x: Any) -> Any:
        self.n += 1
        return self.fn(x)


def drive() -> DriveLog:
    return simulate_drive("city", 10.0, 6, hz=5.0, model=DEFAULT_START_MODEL, lead_in_s=20.0)


def measured(d: DriveLog, model: GyroModel, seed: int = 1) -> DriveLog:
    assert d.omega_truth is not None
    t = d.t
    tc = 15.0 + 8.0 * (1.0 - np.exp(-t / 100.0)) - 5.0 * np.clip((t - 180.0) / 60.0, 0.0, 1.0)
    tc = tc + 1.5 * np.sin(2.0 * np.pi * t / 70.0)
    om = model.apply(t, d.omega_truth, tc, np.random.default_rng(seed))
    return replace(d, omega=om, temp_c=tc, heading_truth=None)


# -- 1. noise maximum likelihood --------------------------------------------------------------


def noise_problems() -> list[tuple[str, Fitter, GyroModel, Noise, list[str]]]:
    out = []
    d = drive()
    bi = DEFAULT_START_MODEL.with_effect(BiasInstability(sigma_dps=0.1, tau_s=5.0))
    data = prepare(measured(d, bi))
    out.append(
        (
            "drive, bias instability (2)",
            Fitter(data),
            bi,
            Noise(0.0, 0.0, 0.03, 20.0),
            ["bi_sigma", "bi_tau"],
        )
    )
    rw = DEFAULT_START_MODEL.with_effect(RateRandomWalk(k_dps_per_sqrt_s=0.005))
    data = prepare(measured(d, rw))
    out.append(("drive, random walk (1)", Fitter(data), rw, Noise(0.0, rrw_k=1e-3), ["rrw_k"]))
    log, _ = phone_log(0)
    data = prepare(log, standstill=True)
    m = (
        DEFAULT_START_MODEL.with_effect(Bandwidth(cutoff_hz=0.2))
        .with_effect(BiasInstability(sigma_dps=0.006, tau_s=300.0))
        .with_effect(RateRandomWalk(k_dps_per_sqrt_s=1.5e-4))
    )
    out.append(
        (
            "phone 6 h, GM + RW (3)",
            Fitter(data),
            m,
            Noise(0.0, 0.0, 0.01, 100.0, 5e-4),
            ["bi_sigma", "bi_tau", "rrw_k"],
        )
    )
    log, _ = imu_log(0)
    data = prepare(log, standstill=True)
    m = DEFAULT_START_MODEL.with_effect(
        TemperatureBias(coeff_dps_per_c=0.026, ref_temp_c=20.0)
    ).with_effect(RateRandomWalk(k_dps_per_sqrt_s=8e-5))
    out.append(("IMU 23 h, random walk (1)", Fitter(data), m, Noise(0.0, rrw_k=1e-3), ["rrw_k"]))
    return out


def bench_noise() -> list[Row]:
    from scipy.optimize import minimize

    rows: list[Row] = []
    for label, f, model, start, which in noise_problems():
        d, db = f.dbar(model)
        wv = float(np.var(np.diff(f.data.omega - d))) / 2.0
        noise = replace(start, white_var=wv)
        nll, x0, _ = f.noise_problem(noise, db, which)
        lo = [math.log(1e-9)] * len(which)
        hi = [math.log(10.0)] * len(which)
        for i, w in enumerate(which):
            if w == "bi_tau":
                lo[i], hi[i] = math.log(f.bi_tau_bounds[0]), math.log(f.bi_tau_bounds[1])
        bounds = list(zip(lo, hi))
        for name in (
            "hand-written Nelder-Mead",
            "scipy Nelder-Mead (hdrd gap)",
            "scipy Powell",
            "scipy L-BFGS-B",
        ):
            c = Counted(nll)
            t0 = time.perf_counter()
            if name.startswith("hand"):
                x = nelder_mead(c, x0, scale=0.7, iters=60 * len(which))
            elif "hdrd" in name:
                x = minimize_simplex(c, x0, np.array(lo), np.array(hi))
            else:
                x = minimize(c, x0, method=name.split()[1], bounds=bounds).x
            dt = time.perf_counter() - t0
            rows.append({"problem": label, "method": name, "nll": nll(x), "nfev": c.n, "s": dt})
        best = min(r["nll"] for r in rows if r["problem"] == label)
        for r in rows:
            if r["problem"] == label:
                r["dnll"] = r["nll"] - best
        print(f"noise ML {label}: done", flush=True)
    return rows


# -- 2. deterministic least squares -----------------------------------------------------------


def det_problems() -> list[tuple[str, GapData, GyroModel, bool]]:
    d = drive()
    out = []
    hidden = DEFAULT_START_MODEL.with_effect(
        TemperatureBias(coeff_dps_per_c=0.03, ref_temp_c=25.0)
    ).with_effect(ScaleFactor(error=0.03))
    start = DEFAULT_START_MODEL.with_effect(
        TemperatureBias(coeff_dps_per_c=0.0, ref_temp_c=18.0, quad_dps_per_c2=1e-6)
    ).with_effect(ScaleFactor(error=0.0))
    out.append(("temperature (quadratic) + scale, 4", prepare(measured(d, hidden)), start, True))
    hidden = DEFAULT_START_MODEL.with_effect(WarmupTransient(amplitude_dps=0.3, tau_s=60.0))
    start = DEFAULT_START_MODEL.with_effect(WarmupTransient(amplitude_dps=0.1, tau_s=200.0))
    out.append(("warm-up (log tau), 3", prepare(measured(d, hidden)), start, False))
    hidden = DEFAULT_START_MODEL.with_effect(TimeOffset(delay_s=0.2))
    start = DEFAULT_START_MODEL.with_effect(TimeOffset(delay_s=0.0))
    out.append(("time offset, 2", prepare(measured(d, hidden)), start, False))
    hidden = DEFAULT_START_MODEL.with_effect(TimeOffset(delay_s=4.0))
    out.append(
        ("time offset 4 s beyond the 3 s bound, 2", prepare(measured(d, hidden)), start, False)
    )
    return out


def bench_det() -> list[Row]:

    from hdrd.analysis.gap.fit import _free_det  # the bench measures the production problem

    rows: list[Row] = []
    for label, data, model, quad in det_problems():
        f = Fitter(data)
        free = _free_det(model, quad)
        d, db = f.dbar(model)
        wv = float(np.var(np.diff(data.omega - data.truth_filled - d))) / 2.0
        wh = Whitener(data, Noise(white_var=wv))
        res, th0, h = f.det_problem(model, free, wh)
        lo = np.full(th0.shape[0], -np.inf)
        hi = np.full(th0.shape[0], np.inf)
        for i, (eff, _p, kind, _) in enumerate(free):
            if kind == "log":
                lo[i], hi[i] = math.log(f.tau_bounds[0]), math.log(f.tau_bounds[1])
            if eff == "time_offset":
                lo[i], hi[i] = -3.0, 3.0
        for name in ("hand-written Levenberg-Marquardt", "scipy least_squares trf (hdrd gap)"):
            c = Counted(res)
            t0 = time.perf_counter()
            if name.startswith("hand"):
                th = levenberg_marquardt(c, th0, h)
            else:
                th = least_squares_bounded(c, th0, h, lo, hi)
            dt = time.perf_counter() - t0
            r = res(th)
            m = with_params(model, free, th, f.tau_bounds)
            vals = {
                f"{e}.{p}": float(getattr(m.get(e), p)) for e, p, _, _ in free if e != "static_bias"
            }
            rows.append(
                {
                    "problem": label,
                    "method": name,
                    "cost": float(r @ r),
                    "nfev": c.n,
                    "s": dt,
                    "params": vals,
                }
            )
        print(f"least squares {label}: done", flush=True)
    return rows


# -- 3. chi-squared tail ----------------------------------------------------------------------


def bench_chi2() -> Row:
    from scipy.stats import chi2

    worst = 0.0
    for k in range(1, 13):
        for x in np.logspace(-2, 3.5, 60):
            ours, ref = chi2_sf(float(x), k), float(chi2.sf(x, k))
            if ref > 1e-300:
                worst = max(worst, abs(ours - ref) / ref)
    n = 20000
    t0 = time.perf_counter()
    for i in range(n):
        chi2_sf(10.0 + i * 1e-4, 2)
    ours_us = (time.perf_counter() - t0) / n * 1e6
    t0 = time.perf_counter()
    for i in range(n // 10):
        chi2.sf(10.0 + i * 1e-4, 2)
    scipy_us = (time.perf_counter() - t0) / (n // 10) * 1e6
    imp = []
    for _ in range(3):
        out = subprocess.run(
            [sys.executable, "-X", "importtime", "-c", "import numpy, scipy.optimize, scipy.stats"],
            capture_output=True,
            text=True,
            check=True,
        ).stderr
        cum = {
            ln.split("|")[2].strip(): int(ln.split("|")[1])
            for ln in out.splitlines()
            if ln.count("|") == 2 and ln.split("|")[1].strip().isdigit()
        }
        imp.append((cum.get("scipy.stats", 0)) / 1e3)
    return {"rel_diff": worst, "ours_us": ours_us, "scipy_us": scipy_us, "import_ms": min(imp)}


# -- 4. Allan deviation -----------------------------------------------------------------------


def bench_allan() -> list[Row]:
    import allantools

    rows: list[Row] = []
    log, _ = phone_log(0)
    x = log.omega
    fs = 10.0
    ms = np.unique(np.round(np.logspace(0, math.log10(x.shape[0] // 10), 26))).astype(np.int64)
    taus = ms / fs
    t0 = time.perf_counter()
    ours = allan_deviation_masked(x, np.ones(x.shape[0], bool), fs, ms)
    t_ours = time.perf_counter() - t0
    t0 = time.perf_counter()
    _, ref, _, _ = allantools.oadev(x, rate=fs, data_type="freq", taus=taus)
    t_ref = time.perf_counter() - t0
    rows.append(
        {
            "case": f"{x.shape[0]:,} samples, {ms.shape[0]} taus",
            "rel_diff": float(np.max(np.abs(ours / ref - 1))),
            "ours_s": t_ours,
            "lib": "oadev",
            "lib_s": t_ref,
        }
    )
    # Gaps: 30 handling periods of 60 s masked out.
    valid = np.ones(x.shape[0], bool)
    rng = np.random.default_rng(0)
    for s in rng.integers(0, x.shape[0] - 600, 30):
        valid[s : s + 600] = False
    xn = np.where(valid, x, np.nan)
    t0 = time.perf_counter()
    ours = allan_deviation_masked(x, valid, fs, ms)
    t_ours = time.perf_counter() - t0
    t0 = time.perf_counter()
    tl, ref, _, _ = allantools.gradev(xn, rate=fs, data_type="freq", taus=taus)
    t_ref = time.perf_counter() - t0
    idx = np.searchsorted(taus, tl)  # gradev returns the taus it could use
    same = (idx < taus.shape[0]) & np.isclose(taus[np.minimum(idx, taus.shape[0] - 1)], tl)
    o = ours[idx[same]]
    r = np.asarray(ref)[same]
    ok = np.isfinite(o) & np.isfinite(r) & (r > 0)
    rows.append(
        {
            "case": f"same, 30 gaps of 60 s ({int(ok.sum())} taus compared)",
            "rel_diff": float(np.max(np.abs(o[ok] / r[ok] - 1))),
            "ours_s": t_ours,
            "lib": "gradev",
            "lib_s": t_ref,
        }
    )
    return rows


def _lines(
    noise: list[dict[str, Any]],
    det: list[dict[str, Any]],
    chi: dict[str, Any],
    allan: list[dict[str, Any]],
) -> list[str]:
    """The section's lines: the command and versions, then the noise fits, the least squares,
    chi2_sf and the Allan deviation, each against its library."""
    lines = [
        "Command: `python bench/gap_libraries.py` (scipy "
        + __import__("scipy").__version__
        + ", allantools "
        + __import__("allantools").__version__
        + "). "
        + machine_line(),
        "",
        "Noise maximum likelihood (negative log-likelihood above the best method's; evaluations of the Kalman-whitened likelihood; seconds):",
        "",
        "| problem (parameters) | method | nll - best | evaluations | s |",
        "|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['problem']} | {r['method']} | {r['dnll']:.3g} | {r['nfev']} | {r['s']:.2f} |"
        for r in noise
    ]
    lines += [
        "",
        "Deterministic least squares (whitened sum of squares; evaluations of the simulator's effect code over the log; fitted values):",
        "",
        "| problem (parameters) | method | cost | evaluations | s | fitted |",
        "|---|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['problem']} | {r['method']} | {r['cost']:.6g} | {r['nfev']} | {r['s']:.2f} | "
        + ", ".join(f"{k} {v:.4g}" for k, v in r["params"].items())
        + " |"
        for r in det
    ]
    lines += [
        "",
        f"chi2_sf vs scipy.stats.chi2.sf (k = 1..12, x = 0.01..3000): largest relative difference {chi['rel_diff']:.1e}; "
        f"{chi['ours_us']:.1f} us vs {chi['scipy_us']:.1f} us per call; importing scipy.stats costs {chi['import_ms']:.0f} ms.",
        "",
        "| Allan deviation | largest relative difference | ours, s | library | library, s |",
        "|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['case']} | {r['rel_diff']:.1e} | {r['ours_s']:.3f} | allantools.{r['lib']} | {r['lib_s']:.3f} |"
        for r in allan
    ]
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--no-write", action="store_true", help="print only")
    a = ap.parse_args(argv)
    missing = [m for m in ("scipy", "allantools") if importlib.util.find_spec(m) is None]
    if missing:
        print(
            f"bench/gap_libraries.py compares against {' and '.join(missing)}, not installed: "
            "pip install scipy allantools",
            file=sys.stderr,
        )
        return 1
    print(machine_line(), flush=True)
    noise = bench_noise()
    det = bench_det()
    chi = bench_chi2()
    allan = bench_allan()
    lines = _lines(noise, det, chi, allan)
    text = "\n".join(lines)
    print(text)
    if not a.no_write:
        write_section(
            "gap", "Model gap: our optimisers vs scipy, our Allan deviation vs allantools", text
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
