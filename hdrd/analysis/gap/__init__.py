"""The model-gap workflow: where a gyro error model and a measured log disagree, which effect
explains it, and how much the gap shrinks once that effect is fitted. The reference (truth,
likelihood, fits, choice of effects, the gap, the report) is docs/model-gap.md.

Pure: :func:`prepare` readies a log, :func:`run_gap` runs the loop, :func:`to_report` and
:func:`summary` give its result; one module per stage (listed in the doc), :mod:`.plots` the
figure, :mod:`hdrd.commands.gap` the command. Rates deg/s, + = CCW; effect names and
parameters those of :mod:`hdrd.sim.gyro`.
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
