"""The self-check of HDR+ through GNSS outages: virtual outages on the daemon's own data, the
record of each outage policy, and the policy a real outage uses. Pure.

While the heading is aligned to GPS courses, every :attr:`SelfCheck.every_steps` steps a
*virtual outage* starts: a copy of the estimator's state for each policy, stepped on the same
gyro steps without the courses (nor the GPS speed) for :attr:`SelfCheck.length_steps` steps,
then scored against the aided heading at its end (|yaw difference|, deg). The policies
(:data:`POLICIES`):

- ``frozen``: the driving bias the courses taught, frozen: no stop or road measurement, the
  yaw integrates every step (the baseline a GPS-aided gyro falls back to);
- ``drift-reduced``: HDR+ as it runs without GPS (zero-rate updates at stops, the road's
  evidence of the driving bias).

:class:`OutageRecord` keeps each policy's count and error sums; :meth:`OutageRecord.policy`
is ``frozen`` until the drift-reduced policy has at least :data:`MIN_TRIALS` virtual outages
behind it and a mean error below the frozen one's. A real outage (aided before, no course
now) runs the policy the record favours at its start. A virtual outage uses only the steps
after its start and the aided heading at its end, never a later one: the same mechanism runs,
causal, inside ``hdrd evaluate --outages``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

from hdrd.core.angles import wrap180
from hdrd.core.hdrplus import PlusState, step
from hdrd.core.plusparams import PlusParams
from hdrd.core.steps import StepInput

__all__ = [
    "FROZEN",
    "MIN_TRIALS",
    "POLICIES",
    "REDUCED",
    "OutageRecord",
    "PolicyScore",
    "SelfCheck",
]

FROZEN = "frozen"
REDUCED = "drift-reduced"
POLICIES = (FROZEN, REDUCED)
"""The outage policies, the default first."""

MIN_TRIALS = 3
"""Virtual outages a policy other than ``frozen`` needs behind it before it is used."""


class PolicyScore(NamedTuple):
    """One policy's record: virtual outages scored, the sum of their |heading error| at the
    end, deg, and of its square, deg^2."""

    n: int = 0
    sum_abs_deg: float = 0.0
    sum_sq_deg2: float = 0.0

    @property
    def mean_abs_deg(self) -> float:
        """Mean |heading error| at a virtual outage's end, deg (NaN before one)."""
        return self.sum_abs_deg / self.n if self.n else math.nan

    def add(self, err_deg: float) -> PolicyScore:
        e = abs(err_deg)
        return PolicyScore(self.n + 1, self.sum_abs_deg + e, self.sum_sq_deg2 + e * e)


@dataclass(frozen=True)
class OutageRecord:
    """Each policy's score over the virtual outages of this unit (its trips so far)."""

    scores: tuple[PolicyScore, ...] = tuple(PolicyScore() for _ in POLICIES)

    def score(self, policy: str) -> PolicyScore:
        return self.scores[POLICIES.index(policy)]

    def add(self, policy: str, err_deg: float) -> OutageRecord:
        i = POLICIES.index(policy)
        s = list(self.scores)
        s[i] = s[i].add(err_deg)
        return replace(self, scores=tuple(s))

    def policy(self) -> str:
        """The policy a real outage uses: ``frozen`` until the drift-reduced one has
        :data:`MIN_TRIALS` trials and a lower mean error."""
        f, r = self.score(FROZEN), self.score(REDUCED)
        if r.n >= MIN_TRIALS and f.n >= MIN_TRIALS and r.mean_abs_deg < f.mean_abs_deg:
            return REDUCED
        return FROZEN

    @property
    def trials(self) -> int:
        """Virtual outages scored (each policy is scored on every one)."""
        return min(s.n for s in self.scores)

    def to_dict(self) -> dict[str, Any]:
        """As the unit's state file keeps it: per policy n, mean_abs_deg, rms_deg."""
        out: dict[str, Any] = {}
        for name, s in zip(POLICIES, self.scores):
            out[name] = {
                "n": s.n,
                "mean_abs_deg": round(s.mean_abs_deg, 4) if s.n else None,
                "rms_deg": round(math.sqrt(s.sum_sq_deg2 / s.n), 4) if s.n else None,
            }
        return out

    @classmethod
    def from_dict(cls, data: object) -> OutageRecord:
        """From :meth:`to_dict`'s form; ValueError naming what is wrong."""
        if not isinstance(data, dict):
            raise ValueError(
                "outage_record must be a mapping of policy -> {n, mean_abs_deg, rms_deg}"
            )
        scores = []
        for name in POLICIES:
            d = data.get(name, {"n": 0})
            if not isinstance(d, dict):
                raise ValueError(f"outage_record.{name} must be a mapping")
            n = d.get("n", 0)
            if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= 10**9:
                raise ValueError(f"outage_record.{name}.n must be a count, got {n!r}")
            if n == 0:
                scores.append(PolicyScore())
                continue
            m, r = d.get("mean_abs_deg"), d.get("rms_deg")
            for key, v in (("mean_abs_deg", m), ("rms_deg", r)):
                if (
                    isinstance(v, bool)
                    or not isinstance(v, (int, float))
                    or not (math.isfinite(v) and 0.0 <= v <= 360.0)
                ):
                    raise ValueError(f"outage_record.{name}.{key} must be in 0..360, got {v!r}")
            assert isinstance(m, (int, float)) and isinstance(r, (int, float))
            scores.append(PolicyScore(n, float(m) * n, float(r) ** 2 * n))
        return cls(tuple(scores))


class _Virtual(NamedTuple):
    policy: str
    state: PlusState
    left: int


def frozen_params(params: PlusParams) -> PlusParams:
    """The settings of the ``frozen`` policy: no stop or road measurement."""
    return params.with_(measure=False)


class SelfCheck:
    """Virtual outages while aided (module docstring). Not thread-safe; pure."""

    def __init__(
        self,
        record: OutageRecord = OutageRecord(),
        length_steps: int = 120,
        every_steps: int = 120,
    ) -> None:
        if length_steps < 1 or every_steps < 1:
            raise ValueError(
                "a virtual outage needs at least one step, and one start per step at most"
            )
        self.record = record
        self.length_steps = length_steps
        self.every_steps = every_steps
        self._running: list[_Virtual] = []
        self._since_start = every_steps  # a first one may start at once
        self._params: tuple[PlusParams, PlusParams] | None = None

    def _settings(self, params: PlusParams) -> dict[str, PlusParams]:
        if self._params is None or self._params[0] is not params:
            self._params = (params, frozen_params(params))
        return {FROZEN: self._params[1], REDUCED: params}

    def on_step(
        self,
        before: PlusState,
        inp: StepInput,
        params: PlusParams,
        aided_yaw: float,
        aided: bool,
    ) -> None:
        """One step of the daemon's HDR+: ``before`` its state before the step, ``inp`` the
        step's input, ``aided_yaw`` the yaw it published after it (deg CCW) and ``aided``
        whether a course measured it. Virtual outages advance on the step without its
        course; those that end are scored against ``aided_yaw`` (only while aided: an outage
        that ends in a real one is dropped); a new one starts from ``before`` when due."""
        settings = self._settings(params)
        blind = inp._replace(
            heading_err_deg=math.nan, heading_err_var=math.nan, heading_reset=False
        )
        if (
            aided
            and self._since_start >= self.every_steps
            and before.aided
            and not inp.heading_reset
        ):
            self._running.extend(_Virtual(p, before, self.length_steps) for p in POLICIES)
            self._since_start = 0
        self._since_start += 1
        still: list[_Virtual] = []
        for v in self._running:
            state, out = step(v.state, blind, settings[v.policy])
            if v.left > 1:
                still.append(_Virtual(v.policy, state, v.left - 1))
            elif aided:
                err = wrap180(out.yaw - aided_yaw)
                self.record = self.record.add(v.policy, err)
        self._running = still

    def policy(self) -> str:
        """The policy a real outage starting now uses."""
        return self.record.policy()
