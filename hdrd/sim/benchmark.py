"""A paper-like benchmark: nine simulated training drives mirroring Table II, five test drives.

Pure and fixed by seed: each :class:`DriveSpec` names its road-type legs, its duration and
distance as in the paper's Table II, its cabin temperature profile (the paper's Sec. 5
discussion: some drives started in near-freezing weather and the heater warmed the cabin,
which moved the bias far more than the gyro's nominal drift) and its seed. ``generate`` turns
a spec into a :class:`~hdrd.io.files.drivelog.DriveLog`; nothing is shipped as data.

The paper's numbers (Table II, Eq. 12/13: Eψ in deg without and with HDR) are kept beside each
spec so that reports can show them next to ours.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from hdrd.io.files.drivelog import DriveLog
from hdrd.sim.drive import simulate_legs
from hdrd.sim.gyro import GyroModel
from hdrd.sim.recordings import FittedErrors
from hdrd.sim.vehicle import PROFILES, CabinTemperature, RoadProfile

__all__ = [
    "TEST_DRIVES",
    "TRAIN_DRIVES",
    "VARIANTS",
    "DriveSpec",
    "generate",
    "generate_all",
    "spec_by_name",
]


def _variant(base: str, name: str, **kw: object) -> RoadProfile:
    return replace(PROFILES[base], name=name, **kw)  # type: ignore[arg-type]


VARIANTS: dict[str, RoadProfile] = {
    **PROFILES,
    # City 1: "Mostly straight streets, few turns".
    "city_straight": _variant(
        "city",
        "city_straight",
        straight_m=(200.0, 500.0),
        weights={"turn": 0.15, "stop": 0.2, "curve": 0.1, "none": 0.55},
    ),
    # City 2: "100% downtown streets, over 40 90-degree turns" (11.9 km in 21.6 min).
    "city_grid": _variant(
        "city",
        "city_grid",
        cruise_mps=(10.0, 14.0),
        straight_m=(60.0, 150.0),
        weights={"turn": 0.9, "stop": 0.04, "none": 0.06},
        stop_before_turn=0.1,
        stop_s=(3.0, 25.0),
        accel_mps2=1.5,
    ),
    # Rural 1: "Mostly straight streets, few turns" (16.1 km in 12.9 min).
    "rural_straight": _variant(
        "rural",
        "rural_straight",
        straight_m=(800.0, 3000.0),
        weights={"curve": 0.4, "turn": 0.05, "none": 0.55},
    ),
    # Highway 1: "90% highway, mostly straight".
    "highway_straight": _variant(
        "highway",
        "highway_straight",
        straight_m=(2000.0, 8000.0),
        weights={"curve": 0.25, "lane_change": 0.45, "none": 0.3},
        curve_deg=(5.0, 25.0),
    ),
    # Highway 2 / Highway Mix: "some curving".
    "highway_curvy": _variant(
        "highway",
        "highway_curvy",
        straight_m=(500.0, 2500.0),
        cruise_mps=(25.0, 31.0),
        weights={"curve": 0.7, "lane_change": 0.2, "none": 0.1},
        curve_deg=(15.0, 70.0),
        curve_radius_m=(600.0, 2000.0),
    ),
}
"""Road profiles the benchmark uses: the built-in ones plus the drive-specific variants."""


@dataclass(frozen=True)
class DriveSpec:
    """One benchmark drive. legs: (profile name in VARIANTS, fraction of the drive time)."""

    name: str
    description: str
    minutes: float
    legs: tuple[tuple[str, float], ...]
    seed: int
    temperature: CabinTemperature
    distance_km: float | None = None
    """The paper's distance (Table II), km; our simulated distance lands near it."""
    paper_e_psi_raw: float | None = None
    """The paper's Eψ without HDR (Table II), deg."""
    paper_e_psi_hdr: float | None = None
    """The paper's Eψ with HDR (Table II), deg."""
    model: GyroModel | None = None
    """Gyro error model; None = crs03_default_model()."""


def _t(start: float, end: float, tau: float) -> CabinTemperature:
    return CabinTemperature(start_c=start, end_c=end, tau_s=tau)


TRAIN_DRIVES: tuple[DriveSpec, ...] = (
    DriveSpec(
        "city1",
        "Mostly straight streets, few turns",
        19.4,
        (("city_straight", 1.0),),
        101,
        _t(15.0, 21.0, 600.0),
        10.8,
        17.0,
        3.1,
    ),
    DriveSpec(
        "suburbs",
        "Mostly curving streets in the suburbs",
        24.3,
        (("suburbs", 1.0),),
        102,
        _t(12.0, 21.0, 600.0),
        17.0,
        35.0,
        10.4,
    ),
    DriveSpec(
        "mixed",
        "Mix of city streets, rural roads, and highway",
        20.0,
        (("rural", 0.33), ("highway", 0.33), ("city", 0.34)),
        103,
        _t(6.0, 21.0, 400.0),
        23.6,
        44.0,
        4.7,
    ),
    DriveSpec(
        "rural1",
        "Mostly straight streets, few turns",
        12.9,
        (("rural_straight", 1.0),),
        104,
        _t(6.0, 22.0, 240.0),
        16.1,
        42.0,
        5.5,
    ),
    DriveSpec(
        "rural2",
        "Mostly straight rural roads, some curving suburban streets",
        18.9,
        (("rural_straight", 0.4), ("suburbs", 0.6)),
        105,
        _t(5.0, 22.0, 400.0),
        15.5,
        56.0,
        5.5,
    ),
    DriveSpec(
        "highway1",
        "90% highway, mostly straight",
        52.1,
        (("city", 0.05), ("highway_straight", 0.9), ("city", 0.05)),
        106,
        _t(4.0, 22.0, 700.0),
        91.4,
        184.0,
        6.4,
    ),
    DriveSpec(
        "highway2",
        "90% highway, some curving",
        50.4,
        (("city", 0.05), ("highway_curvy", 0.9), ("city", 0.05)),
        107,
        _t(12.0, 21.0, 900.0),
        80.6,
        63.0,
        9.3,
    ),
    DriveSpec(
        "highwaymix",
        "70% highway with some curving, 30% rural, mostly straight",
        47.6,
        (("highway_curvy", 0.7), ("rural_straight", 0.3)),
        108,
        _t(14.0, 21.0, 600.0),
        81.2,
        32.0,
        7.1,
    ),
    DriveSpec(
        "city2",
        "100% downtown streets, over 40 90-degree turns",
        21.6,
        (("city_grid", 1.0),),
        109,
        _t(3.0, 22.0, 300.0),
        11.9,
        74.0,
        11.3,
    ),
)
"""The nine training drives of the paper's Table II (4.45 h, 348 km in the paper)."""

TEST_DRIVES: tuple[DriveSpec, ...] = (
    DriveSpec(
        "city3",
        "Downtown and residential streets, traffic lights",
        18.0,
        (("city", 1.0),),
        201,
        _t(10.0, 21.0, 500.0),
    ),
    DriveSpec(
        "suburbs2",
        "Curving suburban streets, some stop signs",
        22.0,
        (("suburbs", 1.0),),
        202,
        _t(15.0, 22.0, 600.0),
    ),
    DriveSpec(
        "rural3",
        "Rural roads with curves and a few junctions",
        25.0,
        (("rural", 1.0),),
        203,
        _t(5.0, 21.0, 600.0),
    ),
    DriveSpec(
        "highway3",
        "Highway with gentle curves, city at both ends",
        40.0,
        (("city", 0.05), ("highway", 0.9), ("city", 0.05)),
        204,
        _t(8.0, 21.0, 800.0),
    ),
    DriveSpec(
        "mixed2",
        "Suburbs, highway and downtown",
        30.0,
        (("suburbs", 0.3), ("highway", 0.4), ("city", 0.3)),
        205,
        _t(12.0, 22.0, 500.0),
    ),
)
"""Five further drives of varied types for testing tuned parameters (the paper's Sec. 5.2.3)."""


def spec_by_name(name: str) -> DriveSpec:
    """The train or test spec of that name (ValueError if none)."""
    for s in TRAIN_DRIVES + TEST_DRIVES:
        if s.name == name:
            return s
    names = ", ".join(s.name for s in TRAIN_DRIVES + TEST_DRIVES)
    raise ValueError(f"no benchmark drive named {name!r} (known: {names})")


def generate(
    spec: DriveSpec,
    hz: float = 10.0,
    model: GyroModel | None = None,
    errors: FittedErrors | None = None,
) -> DriveLog:
    """The drive log of a spec (model overrides the spec's gyro model if given; ``errors``:
    the gyro is the one this route draws from the errors real drives showed,
    :meth:`hdrd.sim.recordings.FittedErrors.draw` with the spec's seed)."""
    legs = [(VARIANTS[p], f) for p, f in spec.legs]
    extra: dict[str, str] = {}
    if errors is not None:
        drawn, model = errors.draw(spec.seed)
        extra["gyro_errors_from"] = f"{drawn} ({errors.source})"
    meta = {
        "drive": spec.name,
        "description": spec.description,
        "benchmark": "train" if spec in TRAIN_DRIVES else "test",
    }
    if spec.distance_km is not None:
        meta["paper_distance_km"] = f"{spec.distance_km:g}"
    if spec.paper_e_psi_raw is not None and spec.paper_e_psi_hdr is not None:
        meta["paper_e_psi_raw_deg"] = f"{spec.paper_e_psi_raw:g}"
        meta["paper_e_psi_hdr_deg"] = f"{spec.paper_e_psi_hdr:g}"
    meta.update(extra)
    return simulate_legs(
        legs,
        spec.minutes,
        spec.seed,
        hz=hz,
        model=model if model is not None else spec.model,
        temperature=spec.temperature,
        name=spec.name,
        meta=meta,
    )


def generate_all(
    which: str = "train", hz: float = 10.0, errors: FittedErrors | None = None
) -> list[DriveLog]:
    """All drives of the training ("train", Table II's nine) or test ("test", five) set; with
    ``errors`` (:func:`hdrd.sim.recordings.errors_from`, an ``hdrd gap`` report of real
    drives) each route's gyro is drawn from the errors those drives showed."""
    if which == "train":
        specs = TRAIN_DRIVES
    elif which == "test":
        specs = TEST_DRIVES
    else:
        raise ValueError(f"which must be 'train' or 'test', got {which!r}")
    return [generate(s, hz=hz, errors=errors) for s in specs]
