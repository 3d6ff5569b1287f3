"""The model-gap workflow: where a gyro error model and a measured log disagree, which effect
explains it, and how much the gap shrinks once that effect is fitted (docs/model-gap.md).

Pure core (:func:`prepare`, :func:`run_gap`, :func:`to_report`, :func:`summary` and the
statistics they use; the ``hdrd gap`` command is :mod:`hdrd.commands.gap`), one module per
stage:

=============== =================================================================================
lattice         the log's recording resolution and the ADC lattice its values sit on
truth           the true rate: omega_truth, a heading's fixes, zero wherever the vehicle stands
data            truth rate, blocks: a drive log made ready (:func:`prepare`, :class:`GapData`)
noise           Allan deviation with gaps; the block noise model and its whitening Kalman filter
lowpass         the sensor low-pass seen in neighbouring differences (Whittle likelihood)
dither          a quantizer's mean over the noise that dithers it; that noise read at rest
predict         the deterministic prediction D (with the quantizer's mean where it applies)
white           the white noise's level at the sensor's input and after its low-pass
optimize        Levenberg-Marquardt, Nelder-Mead, chi-squared tail
fit             likelihood, BIC, fitting a model (:class:`Fit`)
candidates      which effects the log can inform, fitting and scoring each candidate
choose          deterministic before stochastic, nested forms, rivals, backward revisions
metric          the gap number: the model simulated under the log's conditions
diagnose        the discrepancy measures and the "where" sentence
search          the loop: choose, refit, revise (:func:`run_gap`)
report          the report JSON and the printed summary
plots           the figure (matplotlib, lazily)
=============== =================================================================================
 Rates deg/s, + = CCW (left
turn); heading compass deg, clockwise from north; time s since the first sample; temperature
deg C. The effect names and parameters are those of :mod:`hdrd.sim.gyro`.

The loop, each step visible in the report:

1. The residual r = omega - truth (truth: ``omega_truth``, else the derivative of the GPS
   course ``heading_truth``, else zero with ``standstill``; zero wherever the vehicle stands)
   is split into the current model's
   *deterministic* prediction D (its bias, gain, lag, clipping effects applied to the true
   rate, noise off) and an unexplained part e = r - D.
2. The model is simulated under the log's conditions (same t, truth, temp_c, speed; several
   seeds) and compared with the measurement: Allan deviation of e against that of the
   simulated e over tau; e against time, temp_c, moving or standing, the true rate and its
   sign, the rate's derivative; the histogram of omega (ADC lattice, clipping rails). The gap (:func:`gap_metric`) condenses it.
3. Every candidate effect not in the model is fitted (Gaussian likelihood of the block-averaged
   residual, whitened by a Kalman filter for the correlated noise effects; lattice likelihood
   for quantization), scored by BIC, and the best one is added only if BIC falls by more than
   :data:`BIC_MARGIN` and the likelihood-ratio test rejects "no such effect" at :data:`ALPHA`.
   Candidates the data cannot tell apart from the best one are reported as ambiguous.
4. The enlarged model is refitted as a whole and re-simulated; repeat until nothing is
   significant.
"""

from hdrd.analysis.gap.candidates import ALPHA, BIC_MARGIN, CANDIDATES
from hdrd.analysis.gap.choose import AMBIGUITY_BIC, AMBIGUITY_R
from hdrd.analysis.gap.data import GapData, GapError, prepare, truth_rate_from_heading
from hdrd.analysis.gap.fit import NOISE_EFFECTS, Fit, deterministic_part, fit_model
from hdrd.analysis.gap.lattice import Lattice, decimal_resolution, detect_lattice
from hdrd.analysis.gap.metric import GAP_METRIC, gap_metric
from hdrd.analysis.gap.noise import allan_deviation_masked
from hdrd.analysis.gap.optimize import chi2_sf
from hdrd.analysis.gap.report import summary, to_report
from hdrd.analysis.gap.search import Ambiguity, GapResult, Step, run_gap

__all__ = [
    "ALPHA",
    "AMBIGUITY_BIC",
    "AMBIGUITY_R",
    "BIC_MARGIN",
    "CANDIDATES",
    "GAP_METRIC",
    "NOISE_EFFECTS",
    "Ambiguity",
    "Fit",
    "GapData",
    "GapError",
    "GapResult",
    "Lattice",
    "Step",
    "allan_deviation_masked",
    "chi2_sf",
    "decimal_resolution",
    "detect_lattice",
    "deterministic_part",
    "fit_model",
    "gap_metric",
    "prepare",
    "run_gap",
    "summary",
    "to_report",
    "truth_rate_from_heading",
]
