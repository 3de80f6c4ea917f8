"""The task interface: every learned policy takes its shapes from the task (not 96x96x3 and 2-D), Push-T's run keys
and records hold as before tasks existed, and a task a policy was not trained on is refused in one line."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from bcbench.errors import BCBenchError
from bcbench.evaluation.config import EvalConfig
from bcbench.evaluation.controller import ChunkedController
from bcbench.evaluation.evaluate import episode_task
from bcbench.policies import learned_policies, make_policy
from bcbench.policies.learned import PolicyRunner
from bcbench.tasks import get_task, task_names, task_of
from tests.tiny import tiny_overrides

LEARNED = learned_policies()


def fake_task(state_dim: int = 7, action_dim: int = 4, image_size: int = 96):
    """A task of other shapes than Push-T's (MetaWorld's: hand, gripper and goal in; a 4-D action out)."""
    return dataclasses.replace(get_task("pusht"), name="fake/task", family="fake", image_size=image_size,
                               state_names=tuple(f"s{i}" for i in range(state_dim)),
                               action_names=tuple(f"a{i}" for i in range(action_dim)),
                               action_low=(-1.0,) * action_dim, action_high=(1.0,) * action_dim,
                               state_range=(-1.0, 1.0), action_hold=(False,) * (action_dim - 1) + (True,))


def test_pusht_is_the_default_and_states_its_shapes_and_rules():
    t = get_task()
    assert t is get_task("pusht") and t.name == "pusht"
    assert (t.image_size, t.state_dim, t.action_dim, t.control_hz, t.max_steps) == (96, 2, 2, 10.0, 300)
    assert (t.test_seed_start, t.validation_seed_start) == (100_000, 200_000)
    assert "pusht" in task_names() and all(n == "pusht" or n.startswith("metaworld/") for n in task_names())
    assert EvalConfig().max_steps == 300 and EvalConfig(max_steps=50).max_steps == 50


@pytest.mark.parametrize("name", ["nope", "metaworld/", "metaworld/no-such-task", ""])
def test_an_unknown_task_is_one_line_naming_the_choices(name):
    if name == "":  # the empty name is the default task, by design (None and "" both mean Push-T)
        assert get_task(name).name == "pusht"
        return
    with pytest.raises(BCBenchError, match="unknown") as err:
        get_task(name)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("name", LEARNED)
def test_every_learned_policy_takes_its_shapes_from_the_task(name):
    task = fake_task()
    torch.manual_seed(0)
    model = make_policy(name, "quick", task, **tiny_overrides(name)).eval()
    assert (model.state_dim, model.action_dim) == (7, 4)
    b = 3
    batch = {"image": torch.rand(b, 2, 3, 96, 96), "agent_pos": torch.rand(b, 2, 7) * 2 - 1,
             "action": torch.rand(b, 16, 4) * 2 - 1}
    if name == "bet":  # its bins are fitted on the actions before training
        model.centres.copy_(torch.rand(model.config.n_bins, 4) * 2 - 1)
    assert torch.isfinite(model.compute_loss(batch))
    with torch.no_grad():
        assert tuple(model.predict_action_chunk(batch).shape) == (b, 16, 4)


@pytest.mark.parametrize("name", ["cnn_mlp", "diffusion"])
def test_pusht_networks_are_unchanged_by_the_task_argument(name):
    """Push-T's network built with the task given is the one built without it, parameter for parameter (the published
    models load into it)."""
    torch.manual_seed(0)
    a = make_policy(name, "quick", **tiny_overrides(name)).state_dict()
    torch.manual_seed(0)
    b = make_policy(name, "quick", get_task("pusht"), **tiny_overrides(name)).state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_a_task_whose_frames_differ_from_the_config_is_refused():
    with pytest.raises(BCBenchError, match="image_size"):
        make_policy("cnn_mlp", "quick", fake_task(image_size=128), **tiny_overrides("cnn_mlp"))


def test_the_controller_holds_still_in_the_task_s_terms_and_checks_the_action_size():
    task = fake_task()
    model = make_policy("cnn_mlp", "quick", task, **tiny_overrides("cnn_mlp")).eval()
    from bcbench.evaluation.benchmark import _normalizer

    runner = PolicyRunner(model, _normalizer(task))
    assert task_of(runner) is task
    ctl = ChunkedController(runner, task=task)
    obs = {"pixels": np.zeros((96, 96, 3), np.uint8), "agent_pos": np.full(7, 0.3, np.float32)}
    ctl.reset(0, obs, seed=0)
    actions = ctl.act([0])
    assert actions[0].shape == (4,)
    assert get_task("pusht").hold_action(obs).shape == (7,) and not task.hold_action(obs).any()  # delta action: 0
    last = np.array([0.5, -0.5, 0.2, 1.0], np.float32)  # waiting: stand still, keep the grip (Push-T: hold)
    assert task.waiting_action(last).tolist() == [0.0, 0.0, 0.0, 1.0]
    assert get_task("pusht").waiting_action(last) is last


def test_evaluation_refuses_a_task_the_policy_was_not_trained_on():
    model = make_policy("cnn_mlp", "quick", fake_task(), **tiny_overrides("cnn_mlp")).eval()
    from bcbench.evaluation.benchmark import _normalizer

    runner = PolicyRunner(model, _normalizer(fake_task()))
    with pytest.raises(BCBenchError, match="trained on fake/task, not pusht"):
        episode_task(runner, "pusht")
    with pytest.raises(BCBenchError, match="acts in Push-T"):
        make_policy("scripted", "quick", fake_task())
    with pytest.raises(BCBenchError, match=r"(made|trained) for fake/task, not pusht|trained on fake/task, not pusht"):
        episode_task(make_policy("random", "quick", fake_task()), "pusht")  # random takes a task, and says which


def test_pusht_run_keys_are_those_from_before_tasks_and_another_task_retrains():
    from bcbench.study.spec import parse_spec

    spec = parse_spec({"study": {"name": "k"}, "run": [{"policy": "cnn_mlp", "preset": "quick", "seeds": [0]}]})
    run = spec.runs[0]
    assert spec.task == "pusht" and run.key(0.1) == run.key(0.1, "pusht")
    assert run.key(0.1, "metaworld/drawer-open") != run.key(0.1)
    mw = parse_spec({"study": {"name": "k", "task": "metaworld/drawer-open", "purpose": "explore",
                               "seed_start": 200_000, "episodes": 50},
                     "run": [{"policy": "cnn_mlp", "preset": "quick", "seeds": [0]}]})
    assert mw.task == "metaworld/drawer-open" and mw.max_steps == get_task("metaworld/drawer-open").max_steps


def test_a_study_of_another_task_refuses_the_scripted_baseline_and_a_folder_of_another_task(tmp_path):
    from bcbench.study import run_study
    from bcbench.study.spec import parse_spec

    study = {"name": "b", "task": "metaworld/drawer-open", "purpose": "explore", "episodes": 50, "seed_start": 200_000}
    with pytest.raises(BCBenchError, match="the scripted baseline acts in Push-T's world"):
        parse_spec({"study": study, "run": [{"policy": "scripted"}]})
    assert parse_spec({"study": study, "run": [{"policy": "random"}]}).runs[0].policy == "random"  # chance, anywhere
    (tmp_path / "spec.json").write_text('{"task": "pusht"}')
    spec = parse_spec({"study": {"name": "b", "task": "metaworld/drawer-open"},
                       "run": [{"policy": "cnn_mlp", "preset": "quick"}]})
    assert spec.rate_hz == 80.0  # latency verdicts at the task's rate
    with pytest.raises(BCBenchError, match="holds a study of pusht, not metaworld/drawer-open"):
        run_study(spec, tmp_path)


def test_more_steps_than_the_simulator_allows_is_one_line():
    with pytest.raises(BCBenchError, match=r"1\.\.500 .*allows no more"):
        EvalConfig(task="metaworld/drawer-open", max_steps=501)
    assert EvalConfig(task="metaworld/drawer-open").max_steps == get_task("metaworld/drawer-open").max_steps


def test_the_safe_rate_sentence_counts_in_the_sweep_s_task_rate():
    from bcbench.analysis.realtime import step_rate

    assert step_rate({"realtime-sync": {}}.values()) == (10.0, "Push-T")  # a record from before tasks
    mw = {"realtime-sync": {"task": get_task("metaworld/drawer-open").describe()}}
    assert step_rate(mw.values()) == (80.0, "metaworld/drawer-open")


def test_random_acts_within_each_tasks_bounds_and_keeps_pusht_as_it_was():
    from bcbench.policies import make_policy
    from bcbench.policies.baselines import BaselineConfig, RandomPolicy

    task = get_task("metaworld/peg-insert-side")
    rand = make_policy("random", "quick", task, seed=3)
    assert rand.task == task.name  # evaluation checks it against the episodes' task
    gens = [torch.Generator().manual_seed(s) for s in (1, 2)]
    chunk = rand.predict_action_chunk({"agent_pos": np.zeros((2, 2, 4)), "generators": gens})
    assert chunk.shape == (2, 16, 4) and chunk.dtype == np.float32
    assert (chunk >= np.array(task.action_low)).all() and (chunk <= np.array(task.action_high)).all()
    assert chunk.min() < -0.5 and chunk.max() > 0.5  # spread over [-1, 1], not Push-T's [0, 512]
    with pytest.raises(BCBenchError, match="the scripted baseline acts in Push-T's world; it has no version"):
        make_policy("scripted", "quick", task)
    # Push-T's random: the numbers its committed scores rest on (u * 512 in float64, then float32), with or without
    # the task given, on both paths (the controller's per-episode generators; the policy's own numpy stream)
    for pusht in (RandomPolicy(BaselineConfig()), make_policy("random", "quick", get_task("pusht"))):
        assert pusht.task == "pusht"
        got = pusht.predict_action_chunk({"agent_pos": np.zeros((1, 2, 2)),
                                          "generators": [torch.Generator().manual_seed(7)]})
        u = torch.rand((1, 16, 2), generator=torch.Generator().manual_seed(7), dtype=torch.float64)
        np.testing.assert_array_equal(got, (u.numpy() * 512.0).astype(np.float32))
        own = pusht.predict_action_chunk({"agent_pos": np.zeros((3, 2, 2))})
        expected = np.random.default_rng(0).uniform(0.0, 512.0, size=(3, 16, 2)).astype(np.float32)
        np.testing.assert_array_equal(own, expected)
