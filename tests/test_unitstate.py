"""The unit's state file beside the bias file (hdrd/io/files/unitstate.py): what its trips showed,
written atomically, versioned, refused in one line when it cannot be used."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from hdrd.core.selfcheck import FROZEN, REDUCED, OutageRecord
from hdrd.io.files.unitstate import (
    VERSION,
    UnitState,
    UnitStateError,
    load_unit_state,
    save_unit_state,
    unit_state_path,
)


def test_a_state_round_trips_and_gives_the_learned_profile(tmp_path: Path) -> None:
    path = tmp_path / "unit.yaml"
    rec = OutageRecord().add(FROZEN, 2.0).add(REDUCED, 1.0)
    save_unit_state(path, UnitState(-0.0871, 0.004, 3, rec, 1733436000.5))
    text = path.read_text()
    assert text.startswith("# hdrd unit state") and text.rstrip().endswith("# end")
    assert f"version: {VERSION}" in text
    back = load_unit_state(path)
    assert back is not None and back.trips == 3 and back.updated == 1733436000.5
    assert back.motion_offset_dps == -0.0871 and back.motion_offset_sd_dps == 0.004
    assert back.outage_record.score(FROZEN).mean_abs_deg == 2.0
    prof = back.profile()
    assert prof is not None and prof.source == "learned" and prof.motion_offset_dps == -0.0871
    assert load_unit_state(tmp_path / "none.yaml") is None  # no state yet: a fresh unit
    assert UnitState().profile() is None
    assert unit_state_path("/var/lib/hdrd/bias.yaml") == Path("/var/lib/hdrd/unit.yaml")


def test_no_offset_learned_is_written_as_none(tmp_path: Path) -> None:
    path = tmp_path / "unit.yaml"
    save_unit_state(path, UnitState(trips=1))
    back = load_unit_state(path)
    assert back is not None and math.isnan(back.motion_offset_dps) and back.trips == 1


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("version: 1\ntrips: 2\n", "truncated"),
        ("version: 2\n# end\n", "version 2, this hdrd reads version 1"),
        ("- 1\n# end\n", "expected a mapping"),
        (
            "version: 1\nmotion_offset_dps: 9.0\nmotion_offset_sd_dps: 0.1\n# end\n",
            "motion_offset_dps = 9.0 must be a number in -5..5",
        ),
        ("version: 1\nmotion_offset_dps: 0.01\n# end\n", "go together"),
        ("version: 1\ntrips: -3\n# end\n", "trips = -3 is not a count"),
        ("version: 1\nfoo: 1\n# end\n", "unknown key 'foo'"),
        (
            "version: 1\noutage_record: {frozen: {n: 1, mean_abs_deg: 500, rms_deg: 1}}\n# end\n",
            "must be in 0..360",
        ),
        ("version: [1\n# end\n", "not valid YAML"),
    ],
)
def test_a_state_that_cannot_be_used_is_refused_in_one_line(
    tmp_path: Path, text: str, why: str
) -> None:
    path = tmp_path / "unit.yaml"
    path.write_text(text)
    with pytest.raises(UnitStateError, match=why) as e:
        load_unit_state(path)
    assert str(path) in str(e.value) and "\n" not in str(e.value)
