"""Figures of the evaluation: the paper's Fig. 5 (heading vs time) and Fig. 6 (Eψ, NEψ bars).

An edge module (it writes files). matplotlib is imported lazily, only when a plot is drawn,
so the rest of hdrd never needs it; without it, :class:`PlotError` says how to install it.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from hdrd.errors import HdrdError
from hdrd.io.files.access import shown_path

if TYPE_CHECKING:  # pragma: no cover
    from hdrd.analysis.evaluate import DriveResult

__all__ = ["PlotError", "plot_evaluation", "plot_to_file", "plotting_unavailable", "pyplot"]

# The paper's Fig. 5: thick blue truth, dotted red uncorrected, dashed green HDR.
_STYLE: dict[str, dict[str, Any]] = {
    "truth": {"color": "tab:blue", "linewidth": 2.5, "label": "truth"},
    "none": {"color": "tab:red", "linestyle": ":", "linewidth": 1.5, "label": "without HDR"},
    "hdr": {"color": "tab:green", "linestyle": "--", "linewidth": 1.2, "label": "with HDR"},
}
_COLS = 3


class PlotError(HdrdError, RuntimeError):
    """Plotting is impossible (matplotlib missing); the message says what to do."""


def plot_to_file(draw: Callable[[str], None], path: str) -> str | None:
    """Run ``draw(path)``; None on success, else the one-line error for the user (matplotlib
    missing, the file not writable, a format matplotlib cannot write). The command-line edges
    share this."""
    try:
        os.makedirs(os.path.dirname(path) or ".", exist_ok=True)  # as every output's folder
        draw(path)
    except PlotError as e:
        return str(e)
    except (OSError, ValueError) as e:
        why = e.strerror if isinstance(e, OSError) and e.strerror else " ".join(str(e).split())
        return f"cannot write {shown_path(path)}: {why}"
    return None


def plotting_unavailable(path: str | None = None) -> str | None:
    """None if plots can be drawn (to ``path``: in a format matplotlib writes, named by its
    suffix), else the one-line error for the user. Commands with ``--plot`` ask this first,
    so it is said before any work is done."""
    try:
        pyplot()
    except PlotError as e:
        return str(e)
    if path is None:
        return None
    from matplotlib.backend_bases import FigureCanvasBase

    suffix = os.path.splitext(path)[1].lstrip(".").lower()
    formats = FigureCanvasBase.get_supported_filetypes()
    if suffix and suffix not in formats:
        return (
            f"--plot {shown_path(path)}: matplotlib cannot write .{suffix} files; name a "
            f"{', '.join('.' + f for f in sorted(formats))} file (.png is usual)"
        )
    return None


def pyplot() -> Any:
    """matplotlib.pyplot on the file-only Agg backend; PlotError if matplotlib is missing."""
    try:
        import matplotlib

        matplotlib.use("Agg")  # files only; never needs a display
        # Text is text: a drive named "$x^$" is not TeX (mathtext would fail to parse it).
        matplotlib.rcParams["text.parse_math"] = False
        import matplotlib.pyplot as plt
    except ImportError:
        raise PlotError(
            "--plot needs matplotlib, which is not installed: pip install 'hdrd[plot]' "
            "(from a source checkout: pip install '.[plot]')"
        ) from None
    return plt


def _unwrapped_truth(truth: np.ndarray, near: float) -> np.ndarray:
    """Truth heading unwrapped (continuous) and shifted by whole turns to start near ``near``."""
    out = np.full(truth.shape, np.nan)
    ok = np.isfinite(truth)
    if not ok.any():
        return out
    u = np.unwrap(truth[ok], period=360.0)
    u += 360.0 * round((near - u[0]) / 360.0)
    out[ok] = u
    return out


def plot_evaluation(results: Sequence[DriveResult], path: str | os.PathLike[str]) -> None:
    """One PNG: a heading-vs-time panel per drive (Fig. 5: truth, without HDR, with HDR; the
    gyro aligned to the truth at its first valid step, headings unwrapped so a turn through
    north does not jump) and, below, bars of Eψ and NEψ per drive (Fig. 6 a, b)."""
    plt = pyplot()
    n = len(results)
    rows = math.ceil(n / _COLS)
    ncols = min(n, _COLS)
    fig = plt.figure(figsize=(5.0 * max(ncols, 2), 3.2 * (rows + 1)), constrained_layout=True)
    grid = fig.add_gridspec(rows + 1, 2 * ncols)
    for i, r in enumerate(results):
        ax = fig.add_subplot(grid[i // _COLS, 2 * (i % _COLS) : 2 * (i % _COLS) + 2])
        t_min = r.t_end / 60.0
        k = int(np.flatnonzero(np.isfinite(r.truth))[0])
        start = float(r.heading["none"][k])
        ax.plot(t_min, _unwrapped_truth(r.truth, start), **_STYLE["truth"])
        for m in r.methods:
            style = dict(_STYLE.get(m, {"linestyle": "-.", "linewidth": 1.2, "label": m}))
            ax.plot(t_min, r.heading[m], **style)
        ax.set_title(f"{r.name} ({r.duration_min:.1f} min)", fontsize=9)
        ax.set_xlabel("time, min")
        ax.set_ylabel("heading, deg (unwrapped)")
        ax.grid(True, alpha=0.3)
        if i == 0:
            ax.legend(fontsize=7)
    names = [r.name for r in results]
    x = np.arange(n)
    methods = results[0].methods
    width = 0.8 / len(methods)
    for j, (metric, label) in enumerate(
        ((lambda r, m: r.e_psi[m], "Eψ, deg"), (lambda r, m: r.ne_psi[m], "NEψ, deg/min"))
    ):
        ax = fig.add_subplot(grid[rows, j * ncols : (j + 1) * ncols])
        for q, m in enumerate(methods):
            color = _STYLE.get(m, {}).get("color")
            lab = _STYLE.get(m, {}).get("label", m)
            ax.bar(
                x + (q - (len(methods) - 1) / 2) * width,
                [metric(r, m) for r in results],
                width,
                label=lab,
                color=color,
            )
        ax.set_xticks(x)
        ax.set_xticklabels(names, rotation=30, ha="right", fontsize=8)
        ax.set_ylabel(label)
        ax.set_title(
            ("(a) average heading error" if j == 0 else "(b) normalized average heading error"),
            fontsize=9,
        )
        ax.grid(True, axis="y", alpha=0.3)
        ax.legend(fontsize=7)
    try:
        fig.savefig(os.fspath(path), dpi=90)
    finally:
        plt.close(fig)
