"""The examination's probes: one table, each probe a named place with what it tests."""

from drem_maniskill.evaluate.probes import (
    FACE_PUSHED, FLOOR_POSITION, HOLD_POSITIONS, PROBES, SIDE_POSITION, SIDE_PUSHED, TURN, TURNED_HOVER, UPRIGHT_HOVER,
)


def test_every_probe_is_named_once_and_says_in_one_line_what_it_tests():
    names = [p.name for p in PROBES]
    assert len(set(names)) == len(names) and "inserted" not in names  # "inserted" is the expert's, read beside them
    assert all(p.tests and "\n" not in p.tests for p in PROBES)


def test_the_fixed_places_come_first_and_the_rest_in_the_quality_files_order():
    assert list(HOLD_POSITIONS) == [p.name for p in PROBES][:len(HOLD_POSITIONS)]
    assert [p.name for p in PROBES][len(HOLD_POSITIONS):] == [FLOOR_POSITION, SIDE_POSITION, SIDE_PUSHED, FACE_PUSHED,
                                                             TURNED_HOVER, UPRIGHT_HOVER]
    assert HOLD_POSITIONS["pressed 3 mm beside"] == (0.003, 0.0, -0.002)
    # The colour spread is read over the fixed places above the face: seven of them.
    assert sum(at[2] > 0 for at in HOLD_POSITIONS.values()) == 7
    turned = {p.name: p.turn for p in PROBES if p.turn is not None}
    assert turned == {TURNED_HOVER: TURN}
    assert {p.name for p in PROBES if p.via is not None} == {SIDE_POSITION, SIDE_PUSHED}
