"""hdrd.core.grades: the table of gyro grades (datasheet presets of the error model), each
parameter with its source, read into typed :class:`Grade` rows that refuse a bad value.

A grade as HDR+'s error model: test_gyronoise.py; as the simulator's gyro, the CLI's
``--grade``: test_sim_grades.py.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import fields

import pytest

from hdrd.core.grades import DEFAULT_GRADE, GM_PEAK, GRADE_TABLE, GRADES, Grade

PARAMS = [f.name for f in fields(Grade) if f.name not in ("name", "description", "sources")]


def test_the_four_grades_exist() -> None:
    assert set(GRADES) >= {"crs03", "phone", "automotive", "tactical"}


@pytest.mark.parametrize("name", GRADES)
def test_every_parameter_has_a_source(name: str) -> None:
    g = Grade.from_table(name)
    cited = {p.strip() for key in g.sources for p in key.split(",")}
    missing = [p for p in PARAMS if p not in cited]
    assert not missing, f"{name}: no source for {missing}"
    assert all(text.strip() for text in g.sources.values())


@pytest.fixture
def extra_grade() -> Iterator[str]:
    """A name under which a test may put a row into the table; removed afterwards."""
    yield "broken"
    GRADE_TABLE.pop("broken", None)


def test_every_row_reads_into_a_grade_with_all_its_values() -> None:
    for name in GRADES:
        g = Grade.from_table(name)
        assert g.name == name and g.description
        for p in PARAMS:
            v = getattr(g, p)
            assert isinstance(v, (int, float)) and math.isfinite(v), (name, p)
            assert v == GRADE_TABLE[name][p]
        assert g.range_dps > 0 and g.rate_hz > 0 and g.white_dps_per_rthz > 0


def test_the_default_is_the_papers_gyro_and_first() -> None:
    assert DEFAULT_GRADE == "crs03" == GRADES[0]
    assert "CRS03" in Grade.from_table(DEFAULT_GRADE).description


def test_the_bias_instability_is_the_allan_floor_of_a_gauss_markov_bias() -> None:
    # The CRS03-04 grade: a Gauss-Markov bias of sigma 0.01 deg/s, whose Allan deviation
    # peaks at GM_PEAK sigma; the grade states that peak.
    assert GM_PEAK == 0.62
    assert Grade.from_table("crs03").bias_instability_dps == pytest.approx(GM_PEAK * 0.01)


def test_an_unknown_grade_names_the_known_ones() -> None:
    with pytest.raises(ValueError, match="unknown gyro grade 'adis'") as e:
        Grade.from_table("adis")
    assert all(name in str(e.value) for name in GRADES)


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("white_dps_per_rthz", math.nan),
        ("bias_tau_s", math.inf),
        ("quant_step_dps", -0.01),
        ("range_dps", "300"),
    ],
)
def test_a_bad_value_in_the_table_is_refused_naming_it(
    extra_grade: str, key: str, value: object
) -> None:
    GRADE_TABLE[extra_grade] = {**GRADE_TABLE["phone"], key: value}
    with pytest.raises(ValueError, match=f"grade broken: {key} = .* must be a finite number >= 0"):
        Grade.from_table(extra_grade)


def test_only_the_turn_on_bias_may_be_negative(extra_grade: str) -> None:
    GRADE_TABLE[extra_grade] = {**GRADE_TABLE["phone"], "startup_bias_dps": -0.5}
    assert Grade.from_table(extra_grade).startup_bias_dps == -0.5
