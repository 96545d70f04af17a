"""Saved models: the round trip keeps Ĥ and says what it is; unusable files are refused with an
ArtifactError; the training data's hash identifies the data."""

import hashlib
import json

import numpy as np
import pandas as pd
import pytest

from trainclimate.data.trajectory import Trajectory
from trainclimate.predict import ARXPredictor, TransientPredictor
from trainclimate.predict.artifact import (
    FORMAT,
    ArtifactError,
    load_predictor,
    save_predictor,
)
from trainclimate.predict.evaluate import evaluate


def trajectories(noise_data, seed, coaches):
    out = []
    for coach, t in zip(coaches, noise_data(seed, [80] * len(coaches)), strict=True):
        time = pd.date_range("2022-03-01 06:00", periods=80, freq="5min", tz="UTC")
        out.append(
            Trajectory(time, t.y, t.u, t.d, campaign="winter-spring", coach=coach, sampling_min=5)
        )
    return out


@pytest.fixture(scope="module")
def fitted(noise_data):
    train = trajectories(noise_data, 31, ["17A", "44A", "124A"])
    val = trajectories(noise_data, 32, ["66A"])
    return evaluate("transient", 5, 2, 3, data_dir=None, split=(train, val))


def test_round_trip_keeps_h_and_the_metadata(fitted, tmp_path):
    model, result = fitted
    path = save_predictor(model, tmp_path / "models" / "tp.npz", validation=result)
    assert path.exists()
    loaded = load_predictor(path)
    assert isinstance(loaded, TransientPredictor)
    np.testing.assert_array_equal(loaded.H, model.H)
    assert (loaded.rho, loaded.horizon, loaded.sampling_min) == (2, 3, 5.0)
    assert loaded.data_hash == model.data_hash and len(loaded.data_hash) == 64
    assert (loaded.n_trajectories, loaded.n_columns) == (3, 3 * 76)
    meta = loaded.metadata
    assert meta["format"] == FORMAT and meta["method"] == "transient"
    assert (meta["rho"], meta["horizon"], meta["sampling_min"]) == (2, 3, 5.0)
    assert meta["signals"]["y"] == [
        {"name": "t_room_up_c", "unit": "degC"},
        {"name": "t_room_mid_c", "unit": "degC"},
        {"name": "t_room_low_c", "unit": "degC"},
    ]
    assert meta["signals"]["u"] == [{"name": "t_ref_c", "unit": "degC"}]
    assert [(s["name"], s["unit"]) for s in meta["signals"]["d"]] == [
        ("t_amb_c", "degC"),
        ("q_gt_w_m2", "W/m2"),
        ("q_gs_w_m2", "W/m2"),
        ("occupancy_pct", "% of seats"),
        ("speed_kmh", "km/h"),
    ]
    assert meta["training"]["data_sha256"] == model.data_hash
    assert meta["validation"]["mae_per_step_c"] == result["mae_per_step_c"]
    assert len(meta["validation"]["mae_per_step_deck_c"]) == 3
    assert meta["validation"]["validation_coaches"] == ["66A"]


def test_a_loaded_model_predicts_identically(fitted, tmp_path, noise_data):
    model, _ = fitted
    loaded = load_predictor(save_predictor(model, tmp_path / "tp.npz"))
    t = noise_data(33, [5])[0]
    args = (t.y[:2], t.u[:2], t.d[:2], t.u[2:], t.d[2:])
    np.testing.assert_array_equal(loaded.predict(*args), model.predict(*args))


def test_the_method_survives_the_round_trip(noise_data, tmp_path):
    arx = ARXPredictor(2, 2).fit(noise_data(34, [60]))
    loaded = load_predictor(save_predictor(arx, tmp_path / "arx.npz"))
    assert isinstance(loaded, ARXPredictor)
    np.testing.assert_array_equal(loaded.H, arx.H)


def test_saving_an_unfitted_model_raises(tmp_path):
    with pytest.raises(RuntimeError, match="not fitted"):
        save_predictor(TransientPredictor(2, 2), tmp_path / "x.npz")


def rewrite(src, dst, H=None, **meta_changes):
    with np.load(src) as data:
        meta = json.loads(str(data["metadata"]))
        H = data["H"] if H is None else H
    for key, value in meta_changes.items():
        if value is None:
            del meta[key]
        else:
            meta[key] = value
    np.savez(dst, H=H, metadata=np.array(json.dumps(meta)))
    return dst


def test_unusable_files_raise_artifact_errors(fitted, tmp_path):
    model, _ = fitted
    good = save_predictor(model, tmp_path / "good.npz")
    raw = good.read_bytes()
    (tmp_path / "truncated.npz").write_bytes(raw[: len(raw) // 2])  # an interrupted write
    (tmp_path / "empty.npz").write_bytes(b"")
    (tmp_path / "noise.npz").write_bytes(np.random.default_rng(0).bytes(500))
    (tmp_path / "text.npz").write_text("H = [[1, 2]]")
    np.savez(tmp_path / "no_h.npz", metadata=np.array("{}"))
    np.savez(tmp_path / "bad_json.npz", H=model.H, metadata=np.array("{not json"))
    np.savez(tmp_path / "list_meta.npz", H=model.H, metadata=np.array("[1, 2]"))
    cases = {
        "truncated.npz": "not a trainclimate model file",
        "empty.npz": "not a trainclimate model file",
        "noise.npz": "not a trainclimate model file",
        "text.npz": "not a trainclimate model file",
        "no_h.npz": "not a trainclimate model file",
        "bad_json.npz": "not a trainclimate model file",
        "list_meta.npz": "not a JSON object",
        "missing.npz": "model file not found",
    }
    rewrite(good, tmp_path / "wrong_shape.npz", H=model.H[:, :-1])
    cases["wrong_shape.npz"] = r"H has shape \(9, 35\), expected \(9, 36\)"
    spoiled = model.H.copy()
    spoiled[4, 7] = np.nan
    rewrite(good, tmp_path / "nan.npz", H=spoiled)
    cases["nan.npz"] = "all finite"
    rewrite(good, tmp_path / "other_format.npz", format="something-else/2")
    cases["other_format.npz"] = "unsupported model format 'something-else/2'"
    rewrite(good, tmp_path / "no_training.npz", training=None)
    cases["no_training.npz"] = "incomplete model metadata"
    rewrite(good, tmp_path / "bad_rho.npz", rho=0)
    cases["bad_rho.npz"] = "incomplete model metadata"
    for name, message in cases.items():
        with pytest.raises(ArtifactError, match=message):
            load_predictor(tmp_path / name)


def test_the_data_hash_is_the_sha256_of_the_training_data(noise_data):
    data = noise_data(35, [40, 3, 50])
    model = TransientPredictor(1, 2).fit(data)
    by_hand = hashlib.sha256()
    for t in data:
        for a in (t.y, t.u, t.d):
            by_hand.update(np.ascontiguousarray(a, dtype=float).tobytes())
    assert model.data_hash == by_hand.hexdigest()


def test_the_data_hash_changes_with_one_value_and_only_then(noise_data):
    data = noise_data(36, [40, 50])
    reference = TransientPredictor(1, 2).fit(data).data_hash
    # same values in new arrays, another method or chunk size: same hash
    again = noise_data(36, [40, 50])
    assert TransientPredictor(1, 2).fit(again).data_hash == reference
    assert ARXPredictor(3, 1, chunk=5).fit(again).data_hash == reference
    # one value, in any signal, changed by 1e-9
    for name, index in (("y", (3, 2)), ("u", (49, 0)), ("d", (0, 4))):
        changed = noise_data(36, [40, 50])
        getattr(changed[-1], name)[index] += 1e-9
        assert TransientPredictor(1, 2).fit(changed).data_hash != reference
