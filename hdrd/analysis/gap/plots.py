"""Figure of the model-gap workflow: measured vs simulated, before and after each step.

An edge module (it writes a file). matplotlib is imported lazily, only when a plot is drawn;
without it, :class:`PlotError` says how to install it.

One row per accepted step (one row showing the starting model if none was accepted):

- left: Allan deviation of the unexplained residual (omega - truth - the model's deterministic
  part), measured (solid) and simulated by the model under the same conditions (dashed), for
  the model before the step (red, wide and pale, so that it shows where "after" lies on it)
  and after it (blue, thin, on top);
- right: the block residual against the regressor that named the effect (temp_c, time, true
  rate, its derivative; omega's values on the ADC lattice for quantization): before the step
  (grey dots), the fitted effect's contribution (red line) and what is left after it (blue
  rings, so that the grey dots show through).

Titles are wrapped to their panel's width, never cut.
"""

from __future__ import annotations

import os
import textwrap
from typing import TYPE_CHECKING, Any

import numpy as np

from hdrd.analysis.gap.diagnose import regressors
from hdrd.analysis.gap.fit import deterministic_part
from hdrd.analysis.gap.metric import simulate_like
from hdrd.analysis.plots import PlotError, pyplot

if TYPE_CHECKING:  # pragma: no cover
    from hdrd.analysis.gap.search import GapResult, Step

__all__ = ["PlotError", "gap_figure", "plot_gap"]

PANEL_TITLE_CHARS = 80  # characters per line of a panel title (7 pt in a 5.5-inch panel)
FIGURE_TITLE_CHARS = 120  # characters per line of the figure title (10 pt, 11 inches)

_LABEL = {
    "temp_c": "temperature, degC",
    "time_s": "time since power-on, s",
    "true_rate": "true yaw rate, deg/s (+ = CCW)",
    "rate_derivative": "true yaw acceleration, deg/s^2",
    "omega": "omega modulo the lattice step, deg/s",
}


def wrap(text: str, width: int) -> str:
    """``text`` broken into lines of at most ``width`` characters (nothing is dropped)."""
    return "\n".join(textwrap.wrap(text, width, break_on_hyphens=False)) or text


# (label, colour, line width, opacity, z-order): "before" wide and pale underneath, "after" thin
# on top, so that where the two coincide both stay visible.
_BEFORE = ("before", "tab:red", 3.5, 0.45, 2)
_AFTER = ("after", "tab:blue", 1.3, 1.0, 3)


def _allan(ax: Any, res: GapResult, step: Step | None) -> None:
    pairs = (
        [(res.initial_sim, _BEFORE)]
        if step is None
        else [(step.sim_before, _BEFORE), (step.sim_after, _AFTER)]
    )
    for sim, (label, color, lw, alpha, z) in pairs:
        ok = np.isfinite(sim.adev_meas) & np.isfinite(sim.adev_sim)
        style = {"color": color, "linewidth": lw, "alpha": alpha, "zorder": z}
        ax.loglog(sim.taus[ok], sim.adev_meas[ok], "-", label=f"measured ({label})", **style)
        ax.loglog(sim.taus[ok], sim.adev_sim[ok], "--", label=f"model simulated ({label})", **style)
    title = (
        "starting model"
        if step is None
        else f"{step.effect}: gap {step.gap_before:.3g} -> {step.gap_after:.3g}"
    )
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("averaging time tau, s")
    ax.set_ylabel("Allan deviation of residual, deg/s")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)


def _regressor(res: GapResult, step: Step) -> tuple[np.ndarray, str]:
    data = res.data
    name = step.regressor
    regs = regressors(data)
    if name == "omega" or name not in regs:
        return regs["time_s"], "time_s"
    return regs[name], name


def _scatter(ax: Any, res: GapResult, step: Step) -> None:
    data = res.data
    if step.regressor == "omega":
        _lattice(ax, res, step)
        return
    x, name = _regressor(res, step)
    resid = data.block_residual(data.omega)
    after = resid - step.fit_after.dbar
    # The effect's own contribution, and the residual it has to explain once everything else
    # in the enlarged model is accounted for (the partial residual).
    without = step.fit_after.model.without(step.effect)
    own = step.fit_after.dbar - data.block_mean(deterministic_part(data, without))
    partial = after + own
    ax.plot(x, partial, ".", color="0.55", markersize=3.5, label="residual without the effect")
    order = np.argsort(x)
    if np.any(own != 0):
        ax.plot(
            x[order], own[order], "-", color="tab:red", linewidth=1.2, label=f"fitted {step.effect}"
        )
    ax.plot(
        x,
        after,
        "o",
        markerfacecolor="none",
        markeredgecolor="tab:blue",
        markeredgewidth=0.6,
        markersize=3.5,
        label="residual after",
    )
    ax.set_xlabel(_LABEL.get(name, name))
    ax.set_ylabel(f"block residual ({data.block_s:g} s), deg/s")
    ax.set_title(wrap(step.where, PANEL_TITLE_CHARS), fontsize=7)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)


def _lattice(ax: Any, res: GapResult, step: Step) -> None:
    data = res.data
    q = float(step.params.get("step_dps", 0.0)) or 1.0
    mid = float(np.median(data.omega))
    lo, hi = mid - 6.0 * q, mid + 6.0 * q
    bins = np.linspace(lo, hi, 241)
    ax.hist(data.omega, bins=bins, color="tab:blue", alpha=0.8, label="measured omega")
    sim = simulate_like(data, step.fit_before.model, 0, 0)
    ax.hist(sim, bins=bins, histtype="step", color="tab:red", label="model before (simulated)")
    ax.set_xlabel(f"omega near its median, deg/s (lattice step {q:.4g})")
    ax.set_ylabel("samples")
    ax.set_title(wrap(step.where, PANEL_TITLE_CHARS), fontsize=7)
    ax.legend(fontsize=7)


def gap_figure(res: GapResult) -> Any:
    """The figure (a matplotlib Figure; the caller closes it)."""
    plt = pyplot()
    steps = list(res.steps)
    rows = max(1, len(steps))
    fig, axes = plt.subplots(rows, 2, figsize=(11, 1.0 + 3.8 * rows), squeeze=False)
    if not steps:
        _allan(axes[0][0], res, None)
        ax = axes[0][1]
        data = res.data
        e = data.block_residual(data.omega) - res.final_fit.dbar
        ax.plot(data.bt[data.bvalid], e, ".", color="tab:blue", markersize=3)
        ax.set_xlabel(_LABEL["time_s"])
        ax.set_ylabel(f"block residual ({data.block_s:g} s), deg/s")
        ax.set_title("no missing effect found", fontsize=9)
        ax.grid(True, alpha=0.3)
    for i, st in enumerate(steps):
        _allan(axes[i][0], res, st)
        _scatter(axes[i][1], res, st)
    fig.suptitle(
        wrap(
            f"hdrd gap {res.data.name}: {' + '.join(res.initial_model.names())} -> "
            f"{' + '.join(res.final_model.names())}",
            FIGURE_TITLE_CHARS,
        ),
        fontsize=10,
    )
    fig.tight_layout()
    return fig


def plot_gap(res: GapResult, path: str | os.PathLike[str]) -> None:
    """Write the figure to ``path`` (format from the extension, e.g. .png, .pdf)."""
    plt = pyplot()
    fig = gap_figure(res)
    try:
        fig.savefig(path, dpi=110)
    finally:
        plt.close(fig)
