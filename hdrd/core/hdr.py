"""The HDR stepper: Heuristic Drift Reduction, Borenstein & Ojeda, SPIE 7305 (2009).

Pure: no I/O, no clock. One step per period T (paper: 1 s) on the block-averaged,
bias-removed yaw rate u_i = mean(omega_raw) - eps0 (Eqs. 2, 11), in deg/s, positive
counter-clockwise seen from above (a left turn). The step equations and the initial state
are those fixed by ``shared/paper/HDR-NOTES.md``::

    x_i     = (T*u_i + tau*x_{i-1}) / (T + tau)          low-pass filter          (Eq. 7)
    y_i     = x_i + I_i                                   filtered corrected rate
    omega_i = u_i + I_i                                   corrected rate, output   (Eq. 5)
    psi_i   = psi_{i-1} + omega_i*T                       yaw, deg CCW             (Eq. 3)
    s_i     = SIGN(y_i)
    r_{i+1} = r_i + 1 if s_i == s_{i-1} else 1            repetition counter
    R_{i+1} = (1 + c1) / (1 + c1 * r_{i+1}**c2)           repetition attenuator    (Eq. 10)
    W_{i+1} = 1 if |y_i| <= theta_w else 0                turn switch              (Eq. 8)
    I_{i+1} = I_i - s_i * W_{i+1} * R_{i+1} * i_c         binary I-controller      (Eqs. 4, 9)

    initial state: x_{-1} = 0, I_0 = 0, psi_{-1} = 0, r_0 = 1, s_{-1} = 0

One definition of the step, :func:`kernel` (plain floats in, plain floats out), called by
every scalar form: :func:`step` (immutable :class:`HdrState` in, new state and
:class:`HdrOutput` out) for the live daemon, :func:`run_batch` over a numpy array for offline
tools, and HDR+'s core (:mod:`hdrd.core.hdrplus`). :func:`run_many`, its one vectorised twin, steps
many parameter sets at once (for tuning); a property test pins it to the kernel to rounding
(numpy's ``power`` may differ from ``math.pow`` in the last bit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

__all__ = [
    "INITIAL_STATE",
    "HdrOutput",
    "HdrParams",
    "HdrState",
    "HdrTrace",
    "attenuation",
    "kernel",
    "run_batch",
    "run_many",
    "step",
]

# Paper, Table III: "A single set of parameters was used for all drives."
I_C_DPS = 0.0422  # nominal increment of I per step, deg/s
TAU_S = 0.75  # low-pass filter time constant, s
THETA_W_DPS = 0.564  # turn threshold, deg/s
C1 = 0.16  # repetition attenuator constant
C2 = 1.80  # repetition attenuator power
# Paper, Sec. 2: "Throughout this paper, Ti = 1 sec."
T_S = 1.0


@dataclass(frozen=True, slots=True)
class HdrParams:
    """HDR parameters; defaults are the paper's Table III (and T = 1 s, Sec. 2).

    ``lowpass``, ``turn_switch`` and ``attenuator`` switch the three enhancements of
    Sec. 4.2 on or off (all off = "basic HDR", Sec. 3.1); ``enabled=False`` freezes I at 0,
    the "no HDR" baseline (static bias removal only: the ``none`` method).
    """

    i_c: float = I_C_DPS
    """Nominal increment of the integrator I per step, deg/s."""
    tau: float = TAU_S
    """Low-pass filter time constant, s (Eq. 7)."""
    theta_w: float = THETA_W_DPS
    """Turn threshold on the filtered corrected rate, deg/s (Eq. 8)."""
    c1: float = C1
    """Repetition attenuator constant, dimensionless (Eq. 10)."""
    c2: float = C2
    """Repetition attenuator power, dimensionless (Eq. 10)."""
    T: float = T_S
    """Step period, s."""
    lowpass: bool = True
    turn_switch: bool = True
    attenuator: bool = True
    enabled: bool = True

    def __post_init__(self) -> None:
        # Plain Python scalars: numpy scalars (e.g. from a tuning grid) would make the sign
        # test a numpy-bool subtraction, and do not serialise to YAML.
        for f in fields(self):
            kind = bool if f.type in ("bool", bool) else float
            object.__setattr__(self, f.name, kind(getattr(self, f.name)))

    def as_dict(self) -> dict[str, float | bool]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


class HdrState(NamedTuple):
    """State carried from step i-1 to step i. Immutable (a tuple).

    x: low-pass filtered rate x_{i-1}, deg/s. I: controller output I_i applied in the next
    step, deg/s. yaw: psi_{i-1}, deg CCW since start. r: repetition counter r_i. s: sign of the
    previous filtered corrected rate, s_{i-1} in {-1, 0, 1}. n: steps taken so far.
    """

    x: float = 0.0
    I: float = 0.0  # noqa: E741 - the paper's symbol
    yaw: float = 0.0
    r: int = 1
    s: int = 0
    n: int = 0


INITIAL_STATE = HdrState()


class HdrOutput(NamedTuple):
    """What one step publishes.

    omega: corrected yaw rate omega_i = u_i + I_i, deg/s CCW (Eq. 5). yaw: psi_i, deg CCW
    since start (Eq. 3). I: controller output applied in this step, deg/s. W: turn switch
    evaluated on this step's filtered rate (1 = straight, I may move; 0 = turning, I frozen).
    R: repetition attenuator for the update made in this step. r: repetition counter for that
    update. filtered: y_i = x_i + I_i, the low-pass filtered corrected rate, deg/s.
    """

    omega: float
    yaw: float
    I: float  # noqa: E741
    W: int
    R: float
    r: int
    filtered: float


def attenuation(r: int, c1: float = C1, c2: float = C2) -> float:
    """Repetition attenuator R(r) = (1 + c1) / (1 + c1 * r**c2) (Eq. 10); R(1) = 1."""
    return (1.0 + c1) / (1.0 + c1 * math.pow(r, c2))


def kernel(
    u: float,
    x: float,
    I: float,  # noqa: E741 - the paper's symbol
    yaw: float,
    r: int,
    s_prev: int,
    i_c: float,
    T: float,
    p: HdrParams,
) -> tuple[float, float, float, int, int, int, float, float, float]:
    """The paper's step, Eqs. 3-10 (module docstring): the one definition of it in hdrd.

    u: this step's bias-removed rate, deg/s CCW. x, I, yaw, r, s_prev: the state carried from
    the previous step (:class:`HdrState`'s fields). i_c: the increment of I, deg/s (the
    paper's constant; HDR+ passes its own). T: this step's length, s (normally p.T). p: the
    switches, tau, theta_w, c1 and c2.
    Returns (x_i, I_{i+1}, psi_i, r, s_i, W, R, y_i, omega_i) as plain floats and ints: the
    batch forms call it once per step, so it builds no objects.
    """
    x = (T * u + p.tau * x) / (T + p.tau) if p.lowpass else u
    y = x + I
    omega = u + I
    yaw = yaw + omega * T
    s = 1 if y > 0.0 else (-1 if y < 0.0 else 0)
    r = r + 1 if s == s_prev else 1
    R = (1.0 + p.c1) / (1.0 + p.c1 * math.pow(r, p.c2)) if p.attenuator else 1.0
    W = 1 if (not p.turn_switch or abs(y) <= p.theta_w) else 0
    I_next = I - s * W * R * i_c if p.enabled else 0.0
    return x, I_next, yaw, r, s, W, R, y, omega


def step(state: HdrState, u: float, params: HdrParams = HdrParams()) -> tuple[HdrState, HdrOutput]:
    """Advance HDR by one period T (:func:`kernel` on an immutable state).

    u: block mean of the raw rate minus the static bias eps0 (Eqs. 2, 11), deg/s CCW.
    Returns the new state and this step's output. Pure.
    """
    x, I_next, yaw, r, s, W, R, y, omega = kernel(
        float(u), state.x, state.I, state.yaw, state.r, state.s, params.i_c, params.T, params
    )
    return (
        HdrState(x=x, I=I_next, yaw=yaw, r=r, s=s, n=state.n + 1),
        HdrOutput(omega=omega, yaw=yaw, I=state.I, W=W, R=R, r=r, filtered=y),
    )


@dataclass(frozen=True)
class HdrTrace:
    """Every step's output of a batch run, as arrays (one element per step)."""

    omega: npt.NDArray[np.float64]
    yaw: npt.NDArray[np.float64]
    I: npt.NDArray[np.float64]  # noqa: E741
    W: npt.NDArray[np.int8]
    R: npt.NDArray[np.float64]
    r: npt.NDArray[np.int64]
    filtered: npt.NDArray[np.float64]
    final: HdrState


def run_batch(
    u: npt.ArrayLike, params: HdrParams = HdrParams(), state: HdrState = INITIAL_STATE
) -> HdrTrace:
    """Run HDR over a whole array of bias-removed step rates u (deg/s CCW): :func:`kernel`
    looped on local floats, so bit-identical to calling :func:`step` in a loop."""
    uu = np.asarray(u, dtype=np.float64)
    n = uu.shape[0]
    out_omega = np.empty(n)
    out_yaw = np.empty(n)
    out_I = np.empty(n)
    out_W = np.empty(n, dtype=np.int8)
    out_R = np.empty(n)
    out_r = np.empty(n, dtype=np.int64)
    out_y = np.empty(n)
    x, I, yaw = float(state.x), float(state.I), float(state.yaw)  # noqa: E741
    r, s = int(state.r), int(state.s)
    i_c, T = params.i_c, params.T
    for i, ui in enumerate(uu.tolist()):
        out_I[i] = I
        x, I, yaw, r, s, out_W[i], out_R[i], out_y[i], out_omega[i] = kernel(  # noqa: E741
            ui, x, I, yaw, r, s, i_c, T, params
        )
        out_yaw[i] = yaw
        out_r[i] = r
    final = HdrState(x=x, I=I, yaw=yaw, r=r, s=s, n=state.n + n)
    return HdrTrace(out_omega, out_yaw, out_I, out_W, out_R, out_r, out_y, final)


def run_many(
    u: npt.ArrayLike,
    i_c: npt.ArrayLike,
    tau: npt.ArrayLike,
    theta_w: npt.ArrayLike,
    c1: npt.ArrayLike,
    c2: npt.ArrayLike,
    T: float = T_S,
) -> npt.NDArray[np.float64]:
    """Yaw (deg CCW) of every step for many parameter sets stepped together.

    u: shape (n,) bias-removed step rates, deg/s. Parameter arguments broadcast to one shape
    (P,). Returns yaw of shape (n, P). All three enhancements on, as in the paper. The
    recursion is sequential in time but vectorised across parameter sets, which is what
    makes tuning thousands of candidates fast.
    """
    uu = np.asarray(u, dtype=np.float64)
    ic, ta, th, k1, k2 = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.float64) for a in (i_c, tau, theta_w, c1, c2))
    )
    P = ic.shape
    x = np.zeros(P)
    I = np.zeros(P)  # noqa: E741
    yaw = np.zeros(P)
    r = np.ones(P)
    s_prev = np.zeros(P)
    T_tau = T + ta
    one_c1 = 1.0 + k1
    out = np.empty((uu.shape[0],) + P)
    for i, ui in enumerate(uu.tolist()):
        x = (T * ui + ta * x) / T_tau
        y = x + I
        yaw = yaw + (ui + I) * T
        out[i] = yaw
        s = np.sign(y)
        r = np.where(s == s_prev, r + 1.0, 1.0)
        R = one_c1 / (1.0 + k1 * np.power(r, k2))
        W = np.abs(y) <= th
        I = I - s * W * R * ic  # noqa: E741
        s_prev = s
    return out
