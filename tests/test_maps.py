"""Task-map errors. J and J̇ẋ of every registered map against finite differences, and its analytic paths
against the autodiff base, are checked in test_registry_derivatives.py."""

import pytest
import torch

from rmpfusion.maps.basic import build_map

AUX = {"c": 2, "r": 1, "c3": 3}


def test_dimension_errors_are_clear():
    with pytest.raises(ValueError, match="offset.origin has dimension 3"):
        build_map({"type": "offset", "origin": [0, 0, 0]}, 2, {})
    with pytest.raises(ValueError, match="aux name 'goal' is not declared"):
        build_map({"type": "offset", "origin": "goal"}, 2, {})
    with pytest.raises(ValueError, match=r"select.indices \[5\] out of range"):
        build_map({"type": "select", "indices": [5]}, 2, {})
    with pytest.raises(ValueError, match="joint_limit.limit has 2 values for 3 joints"):
        build_map({"type": "joint_limit", "side": "upper", "limit": [1, 2]}, 3, {})


def test_missing_aux_at_call_time_names_it():
    m = build_map({"type": "offset", "origin": "c"}, 2, AUX)
    with pytest.raises(KeyError, match="aux state 'c' is required"):
        m(torch.zeros(1, 2), torch.zeros(1, 2), None)
