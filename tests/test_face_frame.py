"""FlexorFrame: the face's whole state as one named, ordered, checked vector."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from eca.agent.face.flexors import FLEXOR_NAMES, N_FLEXORS
from eca.agent.face.frame import DONT_CARE, FlexorFrame


def test_dont_care_is_nan() -> None:
    assert np.isnan(DONT_CARE)


def test_values_are_named_and_ordered_like_the_flexor_set() -> None:
    frame = FlexorFrame(np.linspace(-1.0, 1.0, N_FLEXORS), t_ns=5)
    assert frame.names == FLEXOR_NAMES
    assert list(frame.as_dict()) == list(FLEXOR_NAMES)
    assert frame.get("turn") == -1.0 and frame.get(FLEXOR_NAMES[-1]) == 1.0
    assert frame.t_ns == 5


@given(st.lists(st.floats(-1.0, 1.0), min_size=N_FLEXORS, max_size=N_FLEXORS), st.integers(0, 2**62))
def test_as_dict_and_from_dict_round_trip(values: list[float], t_ns: int) -> None:
    frame = FlexorFrame(np.array(values), t_ns)
    assert FlexorFrame.from_dict(frame.as_dict(), t_ns) == frame


def test_from_dict_relaxes_unnamed_flexors() -> None:
    frame = FlexorFrame.from_dict({"smile_l": 0.5})
    assert frame.get("smile_l") == 0.5
    assert np.count_nonzero(frame.values) == 1


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"smile_x": 0.1}, r"unknown flexor 'smile_x'; known flexors: turn, nod"),
        ({"brow_l": 1.5}, r"flexor 'brow_l' = 1.5 lies outside \[-1.0, 1.0\]"),
        ({"brow_l": float("nan")}, r"flexor 'brow_l' is NaN"),
        ({"brow_l": "up"}, r"flexor 'brow_l' must be a number"),
        ({"brow_l": True}, r"flexor 'brow_l' must be a number"),
    ],
)
def test_from_dict_rejects_bad_input_with_a_clear_message(values: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        FlexorFrame.from_dict(values)


def test_from_dict_says_where_the_values_came_from() -> None:
    with pytest.raises(ValueError, match=r"^face topic: flexor 'nod'"):
        FlexorFrame.from_dict({"nod": 2.0}, where="face topic")


def test_the_constructor_rejects_wrong_shape_nan_and_out_of_range() -> None:
    with pytest.raises(ValueError, match="shape"):
        FlexorFrame(np.zeros(3))
    with pytest.raises(ValueError, match="'look_x' is NaN"):
        FlexorFrame(np.where(np.arange(N_FLEXORS) == 3, np.nan, 0.0))
    with pytest.raises(ValueError, match="'nod' = -2.0 lies outside"):
        FlexorFrame(np.where(np.arange(N_FLEXORS) == 1, -2.0, 0.0))


def test_get_of_an_unknown_flexor_lists_the_known_ones() -> None:
    with pytest.raises(ValueError, match="unknown flexor 'jaw'.*say_ah"):
        FlexorFrame.neutral().get("jaw")


def test_frames_are_immutable_and_do_not_alias_their_input() -> None:
    source = np.zeros(N_FLEXORS)
    frame = FlexorFrame(source)
    source[0] = 0.9
    assert frame.get("turn") == 0.0
    with pytest.raises(ValueError):
        frame.values[0] = 0.5


def test_with_values_changes_only_the_named_flexors() -> None:
    frame = FlexorFrame.neutral(t_ns=7).with_values(smile_l=0.4, nod=-0.2)
    assert frame.get("smile_l") == 0.4 and frame.get("nod") == -0.2 and frame.get("smile_r") == 0.0
    assert frame.t_ns == 7
