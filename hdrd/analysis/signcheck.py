"""Does a drive log's yaw rate turn the way its truth heading does? Pure.

A compass heading counts clockwise, the yaw rate ``omega`` counter-clockwise (+ = a left
turn), so for a gyro of the right sign and unit the heading's change between two GPS fixes is
minus the rate's integral over the same time: d(heading_truth)/dt = -omega. A log whose rate
was recorded with the other sign (an axis pointing down, a converter that forgot the flip)
scores dozens of degrees where it should score one, and nothing else says why; one whose rate
is in rad/s scores as if the gyro barely turned. :func:`check_sign` compares the two over the
drive's turns (where the truth moves fast enough that GPS noise and the gyro's bias do not
matter), :func:`sign_warning` says what is wrong in one line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from hdrd.core.angles import wrap180

__all__ = [
    "FIX_GAP_S",
    "MIN_TURNS",
    "NO_CHECK",
    "TURN_DPS",
    "SignCheck",
    "check_sign",
    "sign_warning",
]

FloatArray = npt.NDArray[np.float64]

TURN_DPS = 5.0
"""A fix interval counts as a turn when the truth heading changes faster than this, deg/s (a
gentle curve; GPS course noise at driving speed is a few tenths of a degree per fix, a gyro's
bias a fraction of a deg/s)."""
FIX_GAP_S = 2.5
"""Fixes further apart than this, s, are not compared (an outage: the heading may have wrapped
more than half a turn)."""
MIN_TURNS = 5
"""Fewest turning fix intervals to judge a drive by."""
FLIPPED_BELOW = -0.5
"""Agreement below this: the rate turns against the heading."""
SCALE_RANGE = (0.2, 5.0)
"""The rate's turns over the heading's outside this range, the two clearly agreeing in sign
(agreement above :data:`AGREES_ABOVE`): a wrong unit (rad/s read as deg/s: 0.017). Real drives
give 0.5 to 1.1 (a GPS course turns sharper than the car between noisy fixes)."""
AGREES_ABOVE = 0.5


@dataclass(frozen=True)
class SignCheck:
    """How the integrated rate follows the truth heading over the turns.

    turns: fix intervals that were turns. agreement: the cosine between the rate's yaw change
    and minus the heading's change over those intervals (+1: the same turns; -1: every turn
    the other way; NaN with no turns). ratio: the rate's yaw change over the heading's, least
    squares (1: the same scale; about -1 flipped; 0.017 a rate in rad/s read as deg/s).
    """

    turns: int
    agreement: float
    ratio: float

    @property
    def judged(self) -> bool:
        return self.turns >= MIN_TURNS and math.isfinite(self.agreement)

    @property
    def flipped(self) -> bool:
        """The rate turns against the heading: its sign is the wrong one."""
        return self.judged and self.agreement < FLIPPED_BELOW

    @property
    def scaled(self) -> bool:
        """The rate agrees in sign but turns far more or far less than the heading."""
        lo, hi = SCALE_RANGE
        return self.judged and self.agreement > AGREES_ABOVE and not (lo <= self.ratio <= hi)


NO_CHECK = SignCheck(0, math.nan, math.nan)


def _fixes(h: FloatArray) -> npt.NDArray[np.int64]:
    """Rows with a heading, a value held over several rows counted once (its first row)."""
    ok = np.flatnonzero(np.isfinite(h))
    if ok.shape[0] > 1:
        ok = ok[np.concatenate(([True], h[ok[1:]] != h[ok[:-1]]))]
    return ok


def check_sign(t_s: FloatArray, omega_dps: FloatArray, heading_deg: FloatArray) -> SignCheck:
    """Compare the integral of ``omega_dps`` (deg/s, + = CCW; its bias left in: over a turn it
    is small) with ``heading_deg`` (compass, deg CW; NaN between fixes) between each pair of
    consecutive fixes at most :data:`FIX_GAP_S` apart where the heading turns faster than
    :data:`TURN_DPS` (``t_s`` in s, strictly increasing)."""
    t = np.asarray(t_s, dtype=np.float64)
    w = np.asarray(omega_dps, dtype=np.float64)
    h = np.asarray(heading_deg, dtype=np.float64)
    fixes = _fixes(h)
    if fixes.shape[0] < 2 or t.shape[0] < 2:
        return NO_CHECK
    # the yaw, deg CCW, at every row: the trapezoid rule over the samples
    yaw = np.concatenate(([0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))))
    a, b = fixes[:-1], fixes[1:]
    dt = t[b] - t[a]
    dh = wrap180(h[b] - h[a])  # clockwise, the short way round
    dg = yaw[b] - yaw[a]
    turn = (dt > 0) & (dt <= FIX_GAP_S) & (np.abs(dh) >= TURN_DPS * dt)
    n = int(np.count_nonzero(turn))
    if n == 0:
        return NO_CHECK
    truth = -dh[turn]  # counter-clockwise, as the rate
    gyro = dg[turn]
    norm = math.sqrt(float(np.dot(truth, truth)) * float(np.dot(gyro, gyro)))
    agreement = float(np.dot(truth, gyro)) / norm if norm > 0 else math.nan
    ratio = float(np.dot(truth, gyro) / np.dot(truth, truth))
    return SignCheck(n, agreement, ratio)


def sign_warning(name: str, check: SignCheck) -> str | None:
    """One line saying what is wrong with a drive's rate against its truth, or None."""
    if check.flipped:
        return (
            f"{name}: omega turns against heading_truth over {check.turns} turns (agreement "
            f"{check.agreement:.2f}): its sign looks flipped; omega is + counter-clockwise (a "
            "left turn), heading_truth clockwise (docs/drive-format.md)"
        )
    if check.scaled:
        return (
            f"{name}: omega turns {check.ratio:.3g} times as far as heading_truth over "
            f"{check.turns} turns: check its unit, deg/s (a rate in rad/s reads 57.3 times too "
            "small)"
        )
    return None
