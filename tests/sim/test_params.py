import json

import numpy as np
import pytest

from trainclimate.sim.params import CoachParams, ParamsError, diversify, load_params, stack


def test_default_parameters_are_valid_and_lambda_columns_sum_to_one():
    p = CoachParams()
    p.validate()
    assert p.distribution.shape == (6, 6)
    np.testing.assert_allclose(p.distribution.sum(axis=0), 1.0)
    assert np.all(p.distribution >= 0)


def test_json_round_trip(tmp_path):
    path = tmp_path / "coach.json"
    path.write_text(json.dumps(CoachParams().to_dict()))
    p = load_params(path)
    assert p.to_dict() == CoachParams().to_dict()


def test_partial_file_overrides_defaults(tmp_path):
    path = tmp_path / "coach.json"
    path.write_text(json.dumps({"window_g": 0.3, "c_room_j_k": [1e5, 5e4, 1e5]}))
    p = load_params(path)
    assert p.window_g == 0.3
    assert p.c_room_j_k[1] == 5e4
    assert p.roof_area_m2 == CoachParams().roof_area_m2


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"bogus": 1}, "unknown coach parameter 'bogus'"),
        ({"c_room_j_k": [-1.0, 5e4, 1e5]}, "'c_room_j_k' must be > 0"),
        ({"c_inv_j_k": [1.0, 2.0]}, "must have shape [3]"),
        ({"window_g": 1.5}, "'window_g' must lie in [0, 1]"),
        ({"ua_room_inv_w_k": [-5.0, 1.0, 1.0]}, "'ua_room_inv_w_k' must be >= 0"),
        ({"window_g": "high"}, "'window_g' must be a number"),
        ({"distribution": (np.eye(6) * 0.9).tolist()}, "column 0 sums to 0.9000, not 1"),
        ({"roof_area_m2": float("nan")}, "'roof_area_m2' must be finite"),
    ],
)
def test_bad_parameters_name_the_problem(data, message):
    with pytest.raises(ParamsError) as err:
        CoachParams.from_dict(data)
    assert message in str(err.value)


def test_bad_files(tmp_path):
    with pytest.raises(ParamsError, match="not found"):
        load_params(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ParamsError, match="not valid JSON"):
        load_params(bad)


def test_diversity_is_seeded_bounded_and_keeps_lambda_stochastic():
    base = CoachParams()
    a = diversify(base, 5, seed=3, spread=0.15)
    b = diversify(base, 5, seed=3, spread=0.15)
    c = diversify(base, 5, seed=4, spread=0.15)
    assert [x.to_dict() for x in a] == [x.to_dict() for x in b]
    assert a[0].to_dict() != c[0].to_dict()
    for p in a:
        p.validate()
        ratio = p.c_inv_j_k / base.c_inv_j_k
        assert np.all((ratio >= 0.85) & (ratio <= 1.15))
        assert not np.allclose(ratio, 1.0)
        np.testing.assert_allclose(p.distribution.sum(axis=0), 1.0)
        # control settings are the same software on every coach
        np.testing.assert_array_equal(p.pid_kp_w_k, base.pid_kp_w_k)


def test_stack_adds_a_coach_axis():
    s = stack(diversify(CoachParams(), 4, seed=0))
    assert s.c_room_j_k.shape == (4, 3)
    assert s.distribution.shape == (4, 6, 6)
    assert s.window_g.shape == (4,)
