"""Too little or degenerate training data: a PredictorDataError that says what is wrong (how many
windows are needed and found, which signal is to blame) — never a NaN model."""

from types import SimpleNamespace

import numpy as np
import pytest

from trainclimate.predict import METHODS, PredictorDataError, TransientPredictor


def with_column(data, block, column, values):
    """Copies of the trajectories with ``block`` ('y', 'u' or 'd') column ``column`` set."""
    out = []
    for t in data:
        arrays = {"y": t.y.copy(), "u": t.u.copy(), "d": t.d.copy()}
        arrays[block][:, column] = values(arrays)
        out.append(SimpleNamespace(**arrays))
    return out


def test_fewer_windows_than_rows_says_how_many_are_needed_and_found(noise_data):
    # ρ = T = 1: 𝒵 has 18 rows; 10 + 1 samples give 9 windows of 2 samples
    data = noise_data(0, [10, 1])
    model = TransientPredictor(1, 1)
    with pytest.raises(PredictorDataError) as err:
        model.fit(data)
    message = str(err.value)
    assert "at least 18 windows of 2 consecutive samples" in message
    assert "got 9 from 1 of 2 trajectories (11 samples)" in message
    assert model.H is None


@pytest.mark.parametrize(("method", "rows"), [("transient", 45), ("subspace", 45), ("arx", 30)])
def test_the_window_count_is_the_boundary(noise_data, method, rows):
    # ρ = 3, T = 2: 45 rows (ARX: 9ρ + 3 = 30 rows of depth ρ + 1)
    depth = 5 if method != "arx" else 4
    with pytest.raises(PredictorDataError, match=f"at least {rows} windows.*got {rows - 1} "):
        METHODS[method](3, 2).fit(noise_data(1, [depth - 1 + rows - 1]))
    model = METHODS[method](3, 2).fit(noise_data(1, [depth - 1 + rows]))
    assert model.n_columns == rows and np.all(np.isfinite(model.H))


@pytest.mark.parametrize("method", list(METHODS))
def test_a_zero_signal_is_named(noise_data, method):
    data = with_column(noise_data(2, [200, 150]), "d", 3, lambda a: 0.0)  # nobody on board
    model = METHODS[method](2, 2)
    with pytest.raises(PredictorDataError, match="rank-deficient: occupancy_pct at t-1 "):
        model.fit(data)
    assert model.H is None


def test_two_identical_signals_name_the_second(noise_data):
    data = with_column(noise_data(3, [200, 150]), "d", 2, lambda a: a["d"][:, 1])  # Q_Gs = Q_Gt
    with pytest.raises(PredictorDataError, match="q_gs_w_m2 at t "):
        TransientPredictor(1, 3).fit(data)


def test_two_identical_outputs_are_named(noise_data):
    data = with_column(noise_data(3, [200, 150]), "y", 2, lambda a: a["y"][:, 1])
    with pytest.raises(PredictorDataError, match="t_room_low_c at t-2 "):
        TransientPredictor(3, 1).fit(data)


def test_a_constant_speed_is_collinear_with_itself_a_step_later(noise_data):
    # a constant row is no combination of other signals, but the next sample's copy of it is
    data = with_column(noise_data(4, [200, 150]), "d", 4, lambda a: 80.0)
    with pytest.raises(PredictorDataError, match="speed_kmh at t "):
        TransientPredictor(2, 2).fit(data)
    with pytest.raises(PredictorDataError, match=r"speed_kmh at t\+1 "):
        TransientPredictor(1, 2).fit(data)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
@pytest.mark.parametrize("method", list(METHODS))
def test_nan_in_the_training_data_is_a_clear_value_error(noise_data, method, bad):
    data = noise_data(5, [100, 100])
    data[1].y[37, 1] = bad
    model = METHODS[method](2, 2)
    with pytest.raises(ValueError, match="NaN or infinite values"):
        model.fit(data)
    assert model.H is None


def test_trajectories_of_different_sampling_times_are_refused(noise_data):
    data = noise_data(6, [100], sampling_min=5) + noise_data(7, [100], sampling_min=10)
    with pytest.raises(PredictorDataError, match="different sampling times"):
        TransientPredictor(1, 1).fit(data)


def test_fit_leaves_no_nan_model_on_barely_sufficient_data(noise_data):
    # exactly as many windows as rows: a square, non-singular 𝒵
    for method in METHODS:
        model = METHODS[method](1, 1).fit(noise_data(8, [19 if method != "arx" else 13]))
        assert np.all(np.isfinite(model.H))
