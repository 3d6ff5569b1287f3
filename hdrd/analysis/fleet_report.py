"""What a fleet's evaluation looks like to a person: the distribution of NEψ per method over
the drives, in a few lines and a plot. Pure, except :func:`plot_fleet`, which writes a PNG
(matplotlib, lazily)."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import numpy as np

from hdrd.analysis.evaluate import DriveResult, method_key
from hdrd.analysis.plots import pyplot

__all__ = ["QUANTILES", "fleet_summary", "plot_fleet"]

QUANTILES = (10, 50, 90)
"""Percentiles of NEψ shown per method."""


def _q(values: Sequence[float], q: float) -> float:
    a = np.asarray(values, dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(np.percentile(a, q)) if a.shape[0] else math.nan


def fleet_summary(results: Sequence[DriveResult], skipped: int = 0) -> str:
    """The distribution over the drives: NEψ's 10th, 50th and 90th percentile and maximum
    (with its drive) per method, and how often the primary method beat ``none``."""
    ms = results[0].methods
    hours = sum(r.duration_min for r in results) / 60.0
    lines = [
        f"fleet: {len(results)} drives evaluated"
        + (f", {skipped} skipped" if skipped else "")
        + f", {hours:.1f} h driven",
        f"{'NEpsi deg/min':<14}"
        + "".join(f"{'p' + str(q):>9}" for q in QUANTILES)
        + f"{'max':>9}  worst drive",
    ]
    for m in ms:
        ne = [r.ne_psi[m] for r in results]
        worst = max(range(len(results)), key=lambda i: ne[i] if math.isfinite(ne[i]) else -1.0)
        lines.append(
            f"  {method_key(m):<12}"
            + "".join(f"{_q(ne, q):>9.3f}" for q in QUANTILES)
            + f"{ne[worst]:>9.3f}  {results[worst].name}"
        )
    primary = ms[-1]
    if primary != "none":
        worse = sum(1 for r in results if r.e_psi[primary] > r.e_psi["none"])
        imp = [r.improvement for r in results]
        lines.append(
            f"improvement Epsi raw / Epsi {method_key(primary)}: median {_q(imp, 50):.2f}x, "
            f"p10 {_q(imp, 10):.2f}x; worse than raw on {worse} of {len(results)} drives"
        )
    return "\n".join(lines)


def plot_fleet(results: Sequence[DriveResult], path: str | os.PathLike[str]) -> None:
    """One PNG: (a) the histogram of NEψ over the drives per method, logarithmic bins, and
    (b) its box plot per method (median, quartiles, 5th-95th percentile whiskers)."""

    plt = pyplot()
    ms = results[0].methods
    data = {m: np.array([r.ne_psi[m] for r in results], dtype=np.float64) for m in ms}
    pos = np.concatenate([v[np.isfinite(v) & (v > 0)] for v in data.values()])
    lo, hi = (float(pos.min()), float(pos.max())) if pos.shape[0] else (1e-3, 1.0)
    if hi <= lo:
        lo, hi = lo / 2, hi * 2
    n_bins = min(60, max(10, round(2 * math.sqrt(len(results)))))
    bins = np.geomspace(lo, hi, n_bins + 1)
    colors = {"none": "tab:red", "hdr": "tab:green", "hdr+": "tab:purple"}
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.5), constrained_layout=True)
    try:
        for m in ms:
            v = data[m][np.isfinite(data[m]) & (data[m] > 0)]
            label = f"{method_key(m)} (median {np.median(v):.3g})" if v.shape[0] else m
            ax1.hist(v, bins=bins, histtype="step", linewidth=1.6, label=label, color=colors.get(m))
        ax1.set_xscale("log")
        ax1.set_xlabel("NEψ, deg/min")
        ax1.set_ylabel("drives")
        ax1.set_title(f"(a) NEψ over {len(results)} drives", fontsize=10)
        ax1.grid(True, alpha=0.3)
        ax1.legend(fontsize=8)
        finite = [data[m][np.isfinite(data[m])] for m in ms]
        ax2.boxplot(finite, whis=(5, 95), showfliers=False)
        ax2.set_xticks(range(1, len(ms) + 1), [method_key(m) for m in ms])
        ax2.set_yscale("log")
        ax2.set_ylabel("NEψ, deg/min")
        ax2.set_title("(b) median, quartiles, 5th-95th percentile", fontsize=10)
        ax2.grid(True, axis="y", alpha=0.3)
        fig.savefig(os.fspath(path), dpi=90)
    finally:
        plt.close(fig)
