"""The model-gap figure: every title whole and inside the figure, the "before" series visible
where "after" lies on it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from hdrd.analysis.gap import GapResult, run_gap
from hdrd.io.files.drivelog import DriveLog
from hdrd.sim import DEFAULT_START_MODEL, simulate_drive
from hdrd.sim.effects import ScaleFactor, TemperatureBias

pytest.importorskip("matplotlib")

from hdrd.analysis.gap.plots import gap_figure  # noqa: E402 - after the skip
from hdrd.analysis.plots import pyplot  # noqa: E402


@pytest.fixture(scope="module")
def result() -> GapResult:
    """Two hidden effects: two steps, each with a long "where" sentence."""
    d = simulate_drive("city", 10.0, 6, hz=5.0, model=DEFAULT_START_MODEL, lead_in_s=20.0)
    assert d.omega_truth is not None
    t = d.t
    temp = 15.0 + 8.0 * (1 - np.exp(-t / 100)) + 1.5 * np.sin(2 * np.pi * t / 70)
    model = DEFAULT_START_MODEL.with_effect(
        TemperatureBias(coeff_dps_per_c=0.03, ref_temp_c=25.0)
    ).with_effect(ScaleFactor(error=0.03))
    omega = model.apply(t, d.omega_truth, temp, np.random.default_rng(1))
    log = DriveLog(t=t, omega=omega, temp_c=temp, omega_truth=d.omega_truth, name="a" * 40)
    res = run_gap(log)
    assert len(res.steps) >= 2
    return res


@pytest.mark.slow  # a whole model-gap search
def test_titles_are_whole_and_inside_the_figure(result: GapResult) -> None:
    plt = pyplot()
    fig = gap_figure(result)
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        box = fig.bbox
        titles = [ax.title for ax in fig.axes] + [fig._suptitle]
        texts = [t.get_text() for t in titles]
        for s in result.steps:
            assert any(" ".join(x.split()) == s.where for x in texts), s.where
        assert all("..." not in x for x in texts)
        for t in titles:
            ext = t.get_window_extent(renderer)
            assert box.x0 - 1 <= ext.x0 and ext.x1 <= box.x1 + 1, t.get_text()
            assert box.y0 - 1 <= ext.y0 and ext.y1 <= box.y1 + 1, t.get_text()
    finally:
        plt.close(fig)


def reddish_pixels(fig: object, ax: object) -> int:
    fig.canvas.draw()  # type: ignore[attr-defined]
    rgba = np.asarray(fig.canvas.buffer_rgba(), dtype=np.float64) / 255.0  # type: ignore[attr-defined]
    b = ax.get_window_extent()  # type: ignore[attr-defined]
    h = rgba.shape[0]
    part = rgba[int(h - b.y1) : int(h - b.y0), int(b.x0) : int(b.x1)]
    r, g, bl = part[..., 0], part[..., 1], part[..., 2]
    return int(np.sum((r - g > 0.2) & (r - bl > 0.2)))


@pytest.mark.slow  # a whole model-gap search
def test_before_series_stays_visible_under_after(result: GapResult) -> None:
    """A step whose model did not change the Allan deviation: "after" lies exactly on "before";
    the "before" curves must still show (red pixels in the Allan panel, outside the legend)."""
    s0 = result.steps[0]
    same = replace(result, steps=(replace(s0, sim_after=s0.sim_before),))
    plt = pyplot()
    fig = gap_figure(same)
    try:
        ax = fig.axes[0]
        ax.get_legend().remove()
        assert reddish_pixels(fig, ax) > 500
    finally:
        plt.close(fig)
