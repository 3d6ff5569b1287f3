"""The gyro's error model: the named physical effects of :mod:`hdrd.sim.effects` composed into a
:class:`GyroModel`, its YAML form (docs/gyro-model.md) and the CRS03-04's default model.

Pure but for :func:`load_model` and :func:`save_model`: :meth:`GyroModel.apply` maps the true
yaw rate (deg/s, + = CCW) to what the gyro and its ADC report, drawing randomness only from
the generator it is given, each effect from a stream of its own
(:data:`hdrd.sim.effects.STREAMS`), in the effects' physical order whatever order the model
lists them in.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import yaml

from hdrd.core.sensor import SensorModel
from hdrd.errors import clipped
from hdrd.io.files.access import (
    MAX_CONFIG_BYTES,
    InputFileError,
    atomic_write_text,
    load_yaml,
    read_limited,
)
from hdrd.sim.effects import (
    EFFECT_NAMES,
    EFFECTS,
    STREAMS,
    Bandwidth,
    BiasInstability,
    Context,
    Effect,
    Quantization,
    RateRandomWalk,
    Saturation,
    ScaleFactor,
    StaticBias,
    TemperatureBias,
    WarmupTransient,
    WhiteNoise,
    effect_from_dict,
)

__all__ = [
    "DEFAULT_START_MODEL",
    "GyroModel",
    "crs03_default_model",
    "load_model",
    "model_text",
    "save_model",
]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class GyroModel:
    """A set of effects (at most one of each name), applied in the fixed physical order."""

    effects: tuple[Effect, ...] = ()

    def __post_init__(self) -> None:
        effects = tuple(self.effects)
        for e in effects:
            if not isinstance(e, Effect) or type(e) not in EFFECTS.values():
                raise ValueError(f"not a gyro effect: {e!r}")
        names = [e.name for e in effects]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"effect(s) listed more than once: {', '.join(dup)}")
        object.__setattr__(self, "effects", tuple(sorted(effects, key=lambda e: e.order)))

    def names(self) -> list[str]:
        """Effect names in the order they apply."""
        return [e.name for e in self.effects]

    def __contains__(self, name: object) -> bool:
        return any(e.name == name for e in self.effects)

    def get(self, name: str) -> Effect | None:
        """The effect of that name, or None if the model lacks it (ValueError: unknown name)."""
        _check_name(name)
        for e in self.effects:
            if e.name == name:
                return e
        return None

    def with_effect(self, effect: Effect) -> GyroModel:
        """A copy with ``effect`` added, or replacing the one of the same name."""
        return GyroModel(tuple(e for e in self.effects if e.name != effect.name) + (effect,))

    def without(self, name: str) -> GyroModel:
        """A copy without the effect ``name`` (unchanged if absent; ValueError: unknown name)."""
        _check_name(name)
        return GyroModel(tuple(e for e in self.effects if e.name != name))

    def to_dict(self) -> dict[str, list[dict[str, Any]]]:
        """``{"effects": [{"name": ..., <param>: <value>}, ...]}`` in physical order."""
        return {"effects": [{"name": e.name, **e.params()} for e in self.effects]}

    @classmethod
    def from_dict(cls, data: Any) -> GyroModel:
        """Inverse of :meth:`to_dict`; ValueError naming unknown effects or parameters."""
        if not isinstance(data, dict) or "effects" not in data:
            raise ValueError("a gyro model must be a mapping with an 'effects' list")
        extra = sorted(set(data) - {"effects"})
        if extra:
            raise ValueError(
                f"unknown key(s) in gyro model: {', '.join(map(str, extra))} (allowed: effects)"
            )
        items = data["effects"]
        if items is None:
            items = []
        if not isinstance(items, list):
            raise ValueError("'effects' must be a list of {name: ..., <param>: ...} mappings")  # noqa: TRY004 - a bad model is a ValueError
        unknown = [
            clipped(repr(name) if not isinstance(name, str) else name, 80)
            for d in items
            if isinstance(d, dict)
            and not (isinstance(name := d.get("name"), str) and name in EFFECTS)
        ]
        if unknown:
            raise ValueError(
                f"unknown effect name(s): {', '.join(unknown)} (known: {', '.join(EFFECT_NAMES)})"
            )
        return cls(tuple(effect_from_dict(d) for d in items))

    def apply(
        self,
        t_s: npt.ArrayLike,
        omega_true_dps: npt.ArrayLike,
        temp_c: npt.ArrayLike | None,
        rng: np.random.Generator,
        speed_mps: npt.ArrayLike | None = None,
    ) -> FloatArray:
        """The gyro's output (deg/s, + = CCW, bias included) for the true rate at times t_s.

        t_s: strictly increasing sample times, s (power-on = t_s[0]). temp_c: temperature per
        sample, deg C (NaN gaps are interpolated; None is allowed without temperature_bias).
        speed_mps: the vehicle's speed per sample, m/s (NaN gaps interpolated; None is allowed
        without motion_offset). Randomness comes from ``rng`` only (one draw seeds a separate
        stream per effect, :data:`STREAMS`, so adding or removing an effect leaves the others'
        noise unchanged).
        """
        t = np.asarray(t_s, dtype=np.float64)
        x = np.array(omega_true_dps, dtype=np.float64)
        n = int(t.shape[0])
        if t.ndim != 1 or x.shape != t.shape:
            raise ValueError(
                f"t_s and omega_true_dps must be 1-D of equal length ({t.shape} vs {x.shape})"
            )
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(x))):
            raise ValueError("t_s and omega_true_dps must be finite")
        if n > 1 and np.any(np.diff(t) <= 0):
            raise ValueError("t_s must be strictly increasing")
        temp = _per_sample("temp_c", temp_c, n)
        speed = _per_sample("speed_mps", speed_mps, n)
        base = int(rng.integers(0, 2**63 - 1))
        if n == 0:
            return x
        dt = np.empty(n)
        if n > 1:
            dt[1:] = np.diff(t)
            dt[0] = float(np.median(dt[1:]))
        else:
            dt[0] = 1.0
        t0 = t - t[0]
        for e in self.effects:
            ctx = Context(t0, dt, temp, np.random.default_rng([base, STREAMS[e.name]]), speed)
            x = e.apply(x, ctx)
        return x


def _check_name(name: str) -> None:
    if name not in EFFECTS:
        raise ValueError(f"unknown effect name {name!r} (known: {', '.join(EFFECT_NAMES)})")


def _per_sample(what: str, values: npt.ArrayLike | None, n: int) -> FloatArray | None:
    """A column of one value per sample (a scalar: the same for all), NaN gaps interpolated;
    None if absent or all NaN."""
    if values is None:
        return None
    arr = np.array(values, dtype=np.float64)
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if arr.shape != (n,):
        raise ValueError(f"{what} must have one value per sample ({arr.shape} vs {n})")
    ok = np.isfinite(arr)
    if ok.all():
        return arr
    if not ok.any():
        return None
    idx = np.arange(n)
    return np.interp(idx, idx[ok], arr[ok])


# -- defaults and files -------------------------------------------------------------------------


def crs03_default_model() -> GyroModel:
    """A CRS03-04-like gyro on a 16-bit ADC (values plausible for the part, not a datasheet):

    - static bias 1.0 deg/s (the paper measured eps0 = 1.432 deg/s on its unit);
    - warm-up transient 0.02 deg/s settling with tau 90 s after power-on;
    - temperature coefficient 0.008 deg/s/degC at 25 degC, -0.0001 deg/s/degC^2 (steeper when
      cold: 0.012 deg/s/degC at 5 degC): a cabin warming from 5 to 21 degC moves the bias by
      ~0.17 deg/s, the paper's Sec. 5 explanation of its large uncorrected errors (the bias
      over -40..85 degC stays within the part's +/-3 deg/s);
    - bias instability 0.01 deg/s, tau 300 s, and rate random walk 3e-4 deg/s/sqrt(s): in-run
      drift well inside the specified < 1.1 deg/min (0.018 deg/s, 66 deg/h);
    - white noise 0.05 deg/s/sqrt(Hz) (ARW 3 deg/sqrt(h); 0.16 deg/s rms at 10 Hz);
    - scale factor error 0.5 %; bandwidth 10 Hz; saturation +/-200 deg/s;
    - 16-bit ADC quantization, 0.00763 deg/s (hdrd.core.sensor.SensorModel().lsb_dps).
    """
    return GyroModel(
        (
            ScaleFactor(error=0.005),
            StaticBias(bias_dps=1.0),
            WarmupTransient(amplitude_dps=0.02, tau_s=90.0),
            TemperatureBias(coeff_dps_per_c=0.008, ref_temp_c=25.0, quad_dps_per_c2=-0.0001),
            BiasInstability(sigma_dps=0.01, tau_s=300.0),
            RateRandomWalk(k_dps_per_sqrt_s=3e-4),
            WhiteNoise(density_dps_per_rthz=0.05),
            Bandwidth(cutoff_hz=10.0),
            Saturation(limit_dps=200.0),
            Quantization(step_dps=SensorModel().lsb_dps),
        )
    )


DEFAULT_START_MODEL = GyroModel((StaticBias(bias_dps=1.0), WhiteNoise(density_dps_per_rthz=0.05)))
"""The model-gap workflow's starting model: static bias + white noise (CRS03-04-like values)."""


def load_model(path: str | os.PathLike[str]) -> GyroModel:
    """Read a model YAML ``{effects: [{name: static_bias, bias_dps: 0.3}, ...]}``.

    Read as hdrd reads its configuration (:mod:`hdrd.io.files.access`): a regular file of at most
    1 MiB, YAML nested at most 32 deep. Raises ValueError naming the file and what is wrong,
    in one line (OSError if it cannot be read)."""
    try:
        text = read_limited(path, MAX_CONFIG_BYTES).decode("utf-8")
    except InputFileError as exc:
        raise ValueError(f"{path}: cannot be read: {exc}") from None
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not UTF-8 text") from None
    try:
        data = load_yaml(text)
    except InputFileError as exc:
        at = f" at {exc.where}" if exc.where else ""
        raise ValueError(f"{path}: not valid YAML{at}: {exc}") from None
    # yaml only where a file is read: a replay with --bias loads none (tests/test_fastpaths.py)
    from hdrd.io.files.yamlkeys import duplicate_key

    if (dup := duplicate_key(text)) is not None:
        raise ValueError(f"{path}: {dup}")
    try:
        return GyroModel.from_dict(data)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    except (TypeError, OverflowError) as exc:  # a key or value of a type no model has
        raise ValueError(f"{path}: not a gyro model ({type(exc).__name__}: {exc})") from None


def model_text(model: GyroModel) -> str:
    """A model as the YAML :func:`load_model` reads back equal."""
    return (
        "# hdrd gyro error model (docs/gyro-model.md): rates deg/s, + = CCW; times s; temps degC\n"
        + yaml.safe_dump(model.to_dict(), sort_keys=False, default_flow_style=None)
    )


def save_model(
    model: GyroModel,
    path: str | os.PathLike[str],
    inside: str | os.PathLike[str] | None = None,
) -> None:
    """Write a model YAML that :func:`load_model` reads back equal, whole or not at all
    (:func:`hdrd.io.files.access.atomic_write_text`; ``inside``: a drive's model in a folder the
    user named, as its ``inside``)."""
    atomic_write_text(path, model_text(model), inside=inside)
