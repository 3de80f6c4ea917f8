"""Replay-buffer reading, uint8 conversion, validation errors, split, normalizer, window padding, fetch."""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from bcbench.data import MinMaxNormalizer, load_replay_buffer, make_datasets, split_episodes
from bcbench.data.fetch import fetch
from bcbench.data.paths import resolve_dataset
from bcbench.data.sequence import SequenceDataset, fit_normalizer, window_indices
from bcbench.errors import BCBenchError, DatasetError


def test_synthetic_roundtrip_and_uint8(synthetic_zarr, synthetic_buffer):
    buf = load_replay_buffer(synthetic_zarr)
    assert buf.images.dtype == np.uint8 and buf.images.shape == (37, 96, 96, 3)
    expected = np.clip(np.rint(synthetic_buffer.images), 0, 255).astype(np.uint8)
    np.testing.assert_array_equal(buf.images, expected)
    np.testing.assert_array_equal(buf.state, synthetic_buffer.state)
    np.testing.assert_array_equal(buf.action, synthetic_buffer.action)
    assert buf.n_episodes == 3 and list(buf.episode_lengths) == [5, 20, 12]
    assert buf.summary()["episode_length"] == {"min": 5, "max": 20, "mean": 12.3}


def test_real_dataset_structure(real_zarr):
    buf = load_replay_buffer(real_zarr, images=False)
    assert buf.n_episodes == 206 and buf.n_steps == 25650
    assert buf.episode_lengths.min() == 49 and buf.episode_lengths.max() == 246
    assert buf.state.shape == (25650, 5) and buf.action.shape == (25650, 2)
    assert buf.action.min() >= 0 and buf.action.max() <= 512


def _copy(src: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "copy.zarr"
    shutil.copytree(src, dst)
    return dst


def test_missing_key_is_a_clear_error(synthetic_zarr, tmp_path):
    bad = _copy(synthetic_zarr, tmp_path)
    shutil.rmtree(bad / "data" / "action")
    with pytest.raises(DatasetError, match="missing key data/action"):
        load_replay_buffer(bad)


def test_wrong_shape_is_a_clear_error(synthetic_zarr, tmp_path):
    bad = _copy(synthetic_zarr, tmp_path)
    meta = json.loads((bad / "data" / "state" / ".zarray").read_text())
    meta["shape"] = [37, 4]
    meta["chunks"] = [7, 4]
    (bad / "data" / "state" / ".zarray").write_text(json.dumps(meta))
    with pytest.raises(DatasetError, match=r"data/state has shape \(37, 4\)"):
        load_replay_buffer(bad)


def test_corrupt_chunk_is_a_clear_error(synthetic_zarr, tmp_path):
    bad = _copy(synthetic_zarr, tmp_path)
    (bad / "data" / "img" / "1.0.0.0").write_bytes(b"not a blosc chunk at all")
    with pytest.raises(DatasetError, match="cannot read data/img"):
        load_replay_buffer(bad)


def test_inconsistent_episode_ends(synthetic_zarr, tmp_path):
    import zarr

    bad = _copy(synthetic_zarr, tmp_path)
    zarr.open_group(str(bad), mode="r+")["meta/episode_ends"][:] = np.array([5, 25, 30])
    with pytest.raises(DatasetError, match="episode_ends"):
        load_replay_buffer(bad)


def test_not_a_dataset(tmp_path):
    with pytest.raises(DatasetError):
        load_replay_buffer(tmp_path / "nothing-here")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError):
        load_replay_buffer(tmp_path / "empty")


def test_split_is_seeded_disjoint_and_90_10():
    train, val = split_episodes(206, 0.1, seed=0)
    assert len(train) == 185 and len(val) == 21
    assert set(train).isdisjoint(val) and set(train) | set(val) == set(range(206))
    again = split_episodes(206, 0.1, seed=0)
    np.testing.assert_array_equal(train, again[0])
    assert not np.array_equal(val, split_episodes(206, 0.1, seed=1)[1])
    with pytest.raises(BCBenchError):
        split_episodes(10, 1.5)


def test_normalizer_roundtrip_numpy_torch_json(synthetic_buffer):
    norm = fit_normalizer(synthetic_buffer, np.arange(3))
    x = synthetic_buffer.action
    y = norm.normalize("action", x)
    assert y.min() == pytest.approx(-1.0, abs=1e-5) and y.max() == pytest.approx(1.0, abs=1e-5)
    np.testing.assert_allclose(norm.unnormalize("action", y), x, rtol=1e-5, atol=1e-3)
    restored = MinMaxNormalizer.from_dict(json.loads(json.dumps(norm.to_dict())))
    yt = restored.normalize("action", torch.from_numpy(x))
    assert isinstance(yt, torch.Tensor)
    np.testing.assert_allclose(yt.numpy(), y, rtol=1e-6, atol=1e-6)
    with pytest.raises(BCBenchError, match="no statistics"):
        norm.normalize("image", x)


def test_normalizer_uses_training_split_only(synthetic_buffer):
    norm = fit_normalizer(synthetic_buffer, np.array([0]))  # episode 0 = steps 0..4
    assert norm.stats["action"]["max"][0] == 4.0  # action x = step index in the fixture


def test_window_padding_at_both_episode_ends(synthetic_buffer):
    ends = synthetic_buffer.episode_ends  # lengths 5, 20, 12 -> starts 0, 5, 25
    idx = window_indices(ends, np.array([1]), obs_horizon=2, pred_horizon=16, action_horizon=8)
    # starts from -1 to 20 - 16 + 7 = 11: 13 windows
    assert idx.shape == (13, 16)
    assert list(idx[0, :3]) == [5, 5, 6]  # first frame repeated before the episode
    assert idx[-1, 0] == 5 + 11 and list(idx[-1, -5:]) == [24] * 5  # last frame repeated after it
    assert idx.min() >= 5 and idx.max() <= 24  # never crosses into a neighbouring episode
    short = window_indices(ends, np.array([0]), 2, 16, 8)  # an episode shorter than the window
    assert short.min() >= 0 and short.max() <= 4 and len(short) >= 1


def test_a_window_with_more_frames_than_observed_pads_as_its_policy_does(synthetic_buffer):
    ends = synthetic_buffer.episode_ends  # episode 1: steps 5..24
    idx = window_indices(ends, np.array([1]), obs_horizon=16, pred_horizon=16, action_horizon=8, pad_before=1)
    assert idx.shape == (13, 16)  # starts -1 .. 11, as the 2-frame windows: not from -15
    assert list(idx[0, :3]) == [5, 5, 6]
    assert window_indices(ends, np.array([1]), 16, 16, 8).shape == (27, 16)  # the default pads obs_horizon - 1


def test_batches_are_normalised_and_shaped(synthetic_buffer):
    from dataclasses import replace

    buf = replace(synthetic_buffer, images=np.clip(np.rint(synthetic_buffer.images), 0, 255).astype(np.uint8))
    train, val, _norm = make_datasets(buf, val_fraction=0.34, seed=0)
    assert isinstance(train, SequenceDataset) and len(train) > 0 and len(val) > 0
    batch = train.get_batch(np.arange(min(4, len(train))))
    assert batch["image"].shape == (4, 2, 3, 96, 96) and batch["image"].dtype == np.float32
    assert batch["image"].min() >= 0.0 and batch["image"].max() <= 1.0
    assert batch["agent_pos"].shape == (4, 2, 2) and batch["action"].shape == (4, 16, 2)
    assert np.abs(batch["action"]).max() <= 1.0 + 1e-5  # training windows lie inside the fit range


def _zip_dir(src: Path, zip_path: Path) -> Path:
    with zipfile.ZipFile(zip_path, "w") as zf:
        for f in src.rglob("*"):
            zf.write(f, Path("pusht") / src.name / f.relative_to(src))
    return zip_path


def test_fetch_from_zip_and_folder(synthetic_zarr, tmp_path):
    archive = _zip_dir(synthetic_zarr, tmp_path / "pusht.zip")
    dest = tmp_path / "home" / "pusht_cchi_v7_replay.zarr"
    summary = fetch(archive, dest, progress=False)
    assert summary["episodes"] == 3 and summary["steps"] == 37 and dest.is_dir()
    with pytest.raises(DatasetError, match="already exists"):
        fetch(archive, dest, progress=False)
    summary = fetch(synthetic_zarr.parent, dest, force=True, progress=False)  # a folder holding the zarr
    assert summary["episodes"] == 3
    assert load_replay_buffer(dest).n_steps == 37


def test_fetch_rejects_bad_input_and_leaves_nothing(tmp_path, synthetic_zarr):
    not_zip = tmp_path / "pusht.zip"
    not_zip.write_text("hello")
    dest = tmp_path / "out" / "x.zarr"
    with pytest.raises(DatasetError, match="not a zip"):
        fetch(not_zip, dest, progress=False)
    broken = _copy(synthetic_zarr, tmp_path)
    shutil.rmtree(broken / "data" / "img")
    with pytest.raises(DatasetError, match="missing key data/img"):
        fetch(broken, dest, progress=False)
    assert not dest.exists() and list(dest.parent.iterdir()) == []


def test_resolve_dataset_flag_env_and_error(monkeypatch, tmp_path, synthetic_zarr):
    assert resolve_dataset(synthetic_zarr) == synthetic_zarr
    monkeypatch.setenv("BCBENCH_DATA", str(synthetic_zarr))
    assert resolve_dataset() == synthetic_zarr
    monkeypatch.setenv("BCBENCH_DATA", str(tmp_path / "missing"))
    with pytest.raises(DatasetError, match="BCBENCH_DATA"):
        resolve_dataset()
    monkeypatch.delenv("BCBENCH_DATA")
    monkeypatch.setattr("bcbench.data.paths.candidate_paths", lambda: [tmp_path / "nope"])
    with pytest.raises(DatasetError, match="bcbench data fetch"):
        resolve_dataset()
