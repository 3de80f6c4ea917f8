"""The demonstration-count axis (`--demos N`, a study run's `demos`): a run trains on the first N episodes of its
training split, nested across counts, the validation split unchanged; the count is recorded in run.json and in the
study's run key, and a run without it keeps the key and the split it always had."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bcbench.cli import main
from bcbench.data import make_datasets, split_episodes
from bcbench.data.sequence import fit_normalizer
from bcbench.errors import BCBenchError
from bcbench.study.spec_runs import _run_specs
from tests.conftest import make_synthetic_buffer
from tests.tiny import tiny_overrides

LENGTHS = (30, 31, 32, 33, 34, 35, 36, 37, 38, 39)  # 10 episodes: 9 train, 1 held out at val_fraction 0.1


def _episodes(ds) -> set[int]:
    """The episodes a dataset's windows come from (its first index's episode)."""
    ends = ds.buffer.episode_ends
    return {int(np.searchsorted(ends, w[0], side="right")) for w in ds.indices}


def test_demos_keep_the_first_training_episodes_nested_and_leave_validation_alone():
    buf = make_synthetic_buffer(LENGTHS)
    train_all, val_all = split_episodes(len(LENGTHS), 0.1, 0)
    full, val, _ = make_datasets(buf, 0.1, 0)
    assert _episodes(full) == set(train_all.tolist()) and _episodes(val) == set(val_all.tolist())
    seen = []
    for n in (2, 5, 9):
        train, val_n, _ = make_datasets(buf, 0.1, 0, demos=n)
        eps = _episodes(train)
        assert eps == set(train_all[:n].tolist())  # the first n of the training split, by index
        assert _episodes(val_n) == set(val_all.tolist())  # validation does not move with the count
        assert not seen or seen[-1] < eps  # nested: the smaller count's episodes are inside the larger's
        seen.append(eps)
    # the normaliser is fit on the episodes trained on, as a user holding only those would fit it
    few = make_datasets(buf, 0.1, 0, demos=2)[2].to_dict()
    assert few == fit_normalizer(buf, train_all[:2]).to_dict()
    assert few != make_datasets(buf, 0.1, 0)[2].to_dict()
    with pytest.raises(BCBenchError, match="demos 10: the training split has 9 episodes"):
        make_datasets(buf, 0.1, 0, demos=10)


def _run(**extra) -> dict:
    return {"policy": "cnn_mlp", "preset": "quick", "seeds": [0], **extra}


def test_a_study_run_key_holds_the_count_only_when_given():
    plain = _run_specs(0, _run())[0]
    assert plain.demos is None
    ten, fifty = _run_specs(0, _run(demos=10))[0], _run_specs(0, _run(demos=50))[0]
    assert (ten.demos, fifty.demos) == (10, 50)
    keys = {plain.key(0.1), ten.key(0.1), fifty.key(0.1)}
    assert len(keys) == 3  # each count is its own run, trained apart
    # a run without demos hashes exactly what it did before the option existed (its run folders still match)
    import hashlib

    config = plain.config_dict()
    assert config["optim"].pop("val_every") is None  # a newer field at its neutral value is not hashed either
    blob = json.dumps({"policy": "cnn_mlp", "config": config, "val_fraction": 0.1}, sort_keys=True)
    assert plain.key(0.1).endswith(hashlib.sha256(blob.encode()).hexdigest()[:8])
    sparse = _run_specs(0, _run(set={"optim.val_every": 229}))[0]
    assert sparse.key(0.1) != plain.key(0.1)  # set, it is its own run
    for bad in (0, -3, 2.5, True, "10"):
        with pytest.raises(BCBenchError, match=r"\[\[run\]\] #1 \(cnn_mlp\): demos must be a whole number"):
            _run_specs(0, _run(demos=bad))
    with pytest.raises(BCBenchError, match=r"demos applies to a policy that trains, not the random baseline"):
        _run_specs(0, {"policy": "random", "demos": 10})
    from bcbench.study.spec import parse_spec

    base = {"policy": "diffusion", "preset": "quick", "steps": 10, "label": "DP", "demos": 10}
    twice = {**base, "steps": 20, "label": "DP 2x", "doubles": "DP"}
    assert parse_spec({"study": {"name": "d"}, "run": [base, twice]}).runs[1].demos == 10
    with pytest.raises(BCBenchError, match=r"run 'DP 2x' must train on the same demos as 'DP' \(10\), got 50"):
        parse_spec({"study": {"name": "d"}, "run": [base, {**twice, "demos": 50}]})
    with pytest.raises(BCBenchError, match=r"run 'DP 2x' must validate at the cadence of 'DP' \(optim.val_every "
                                           r"None\), got 229"):
        parse_spec({"study": {"name": "d"}, "run": [base, {**twice, "set": {"optim.val_every": 229}}]})


def _sets() -> list[str]:
    sets = {**tiny_overrides("cnn_mlp", max_steps=1), "optim.batch_size": 1}  # one kept episode may be 5 steps
    return [a for k, v in sets.items() for a in ("--set", f"{k}={json.dumps(v)}")]


def test_train_demos_records_the_count_and_trains_on_fewer_windows(synthetic_zarr, tmp_path, capsys):
    runs = {}
    for name, extra in (("all", []), ("one", ["--demos", "1"])):
        runs[name] = tmp_path / name
        assert main(["train", "--policy", "cnn_mlp", "--out", str(runs[name]), "--data", str(synthetic_zarr),
                     "--quiet", *_sets(), *extra]) == 0
    meta = {k: json.loads((d / "run.json").read_text()) for k, d in runs.items()}
    assert "demos" not in meta["all"]["data_split"] and meta["one"]["data_split"]["demos"] == 1
    summary = {k: json.loads((d / "train_summary.json").read_text()) for k, d in runs.items()}
    assert 0 < summary["one"]["train_windows"] < summary["all"]["train_windows"]
    assert summary["one"]["val_windows"] == summary["all"]["val_windows"]
    capsys.readouterr()
    assert main(["train", "--resume", str(runs["one"]), "--demos", "2", "--quiet"]) == 2
    assert "--demos define a new run" in capsys.readouterr().err
    too_many = ["train", "--policy", "cnn_mlp", "--out", str(tmp_path / "x"), "--data", str(synthetic_zarr),
                "--quiet", *_sets(), "--demos", "50"]
    assert main(too_many) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "demos 50: the training split has" in err[0]
    assert not (tmp_path / "x").exists()  # the failed start leaves no run folder
    with pytest.raises(SystemExit) as bad:  # argparse's own one line
        main(["train", "--policy", "cnn_mlp", "--demos", "0", "--quiet"])
    assert bad.value.code == 2 and "--demos: expected a number >= 1" in capsys.readouterr().err


def test_a_study_run_trains_on_its_demos(synthetic_zarr, tmp_path):
    sets = ", ".join(f'"{k}" = {json.dumps(v)}' for k, v in
                     {**tiny_overrides("cnn_mlp", max_steps=1), "optim.batch_size": 1}.items())
    spec = tmp_path / "few.toml"
    spec.write_text(f'[study]\nname = "few"\nepisodes = 1\nmax_steps = 4\nlatency = false\n\n'
                    f'[[run]]\npolicy = "cnn_mlp"\ndemos = 1\nset = {{ {sets} }}\n')
    out = tmp_path / "out"
    assert main(["study", str(spec), "--out", str(out), "--data", str(synthetic_zarr), "--quiet", "--no-report"]) == 0
    (run,) = (out / "runs").iterdir()
    assert json.loads((run / "run.json").read_text())["data_split"]["demos"] == 1
    from bcbench.study.spec import load_spec

    assert run.name == load_spec(spec).runs[0].key(0.1)  # the folder is the run key that holds the count


@pytest.mark.parametrize("name", ["metaworld-explore-1", "metaworld-explore-1-peg", "metaworld-explore-2",
                                  "metaworld-explore-3", "metaworld-explore-4"])
def test_committed_run_folders_match_the_keys_their_spec_gives_today(name):
    """A field added since (at its neutral value) must not rename a finished run: a resumed or restored study would
    train it again."""
    from pathlib import Path

    from bcbench.study.runner import StudyRunner
    from bcbench.study.spec import load_spec

    root = Path(__file__).resolve().parents[1]
    runner = StudyRunner(load_spec(root / "studies" / f"{name}.toml"), root / "results" / name, progress=False)
    keys = {runner.run_dir(r).name for r in runner.spec.runs}
    folders = {p.name for p in (root / "results" / name / "runs").iterdir()}
    assert folders and folders <= keys, folders - keys
