"""The LeRobot v3.0 export and import for any task, not only Push-T: features, names, rate, frame size and task
string from the task; Push-T's export byte for byte what it was before the task interface (the golden digests);
round trips for Push-T and for fake tasks of other widths, rates and frame sizes; `--task` on the data commands."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from bcbench.cli.main import main
from bcbench.data.lerobot_format import DATA_FILE, TASK, export_lerobot, task_text
from bcbench.data.lerobot_import import import_lerobot
from bcbench.data.replay_buffer import ReplayBuffer
from bcbench.errors import DatasetError
from bcbench.tasks import get_task
from tests.conftest import make_synthetic_buffer
from tests.golden import make_lerobot_golden as golden

GOLDEN = Path(__file__).parent / "golden" / "lerobot-export-dc2fca9.json"
LENGTHS = (4, 9, 6)


def fake_task(state: int = 4, image_size: int = 96, hz: float = 80.0, name: str = "fake/task"):
    """A non-Push-T task (4 or 7 state values, 4 actions in [-1, 1]) whose demonstrations are a synthetic buffer."""
    buf = fake_buffer(state, image_size)
    return dataclasses.replace(
        get_task("pusht"), name=name, family="fake", image_size=image_size,
        state_names=tuple(f"q{i}" for i in range(state)), action_names=("dx", "dy", "dz", "grip"),
        action_low=(-1.0,) * 4, action_high=(1.0,) * 4, control_hz=hz, instruction="",
        dataset=lambda path: Path(path or "fake.zarr"), load_buffer=lambda path, images: dataclasses.replace(
            buf, source=str(path), images=buf.images if images else None))


def fake_buffer(state: int = 4, image_size: int = 96, seed: int = 3) -> ReplayBuffer:
    """As MetaWorld's: state = the proprioception, 4-D actions, uint8 frames, no keypoints or contacts."""
    rng = np.random.default_rng(seed)
    n = sum(LENGTHS)
    return ReplayBuffer(state=rng.normal(size=(n, state)).astype(np.float32),
                        action=rng.uniform(-1, 1, (n, 4)).astype(np.float32),
                        episode_ends=np.cumsum(LENGTHS).astype(np.int64),
                        images=rng.integers(0, 256, (n, image_size, image_size, 3), dtype=np.uint8))


def pusht_buffer() -> ReplayBuffer:
    buf = make_synthetic_buffer(LENGTHS)
    buf.images = np.clip(np.rint(buf.images), 0, 255).astype(np.uint8)  # as load_replay_buffer gives them
    return buf


CASES = {"pusht": lambda: (get_task("pusht"), pusht_buffer()),
         "fake4": lambda: (fake_task(), fake_buffer()),
         "fake7-64px-12.5hz": lambda: (fake_task(7, 64, 12.5), fake_buffer(7, 64))}


@pytest.fixture(params=list(CASES))
def case(request):
    return CASES[request.param]()


# ------------------------------------------------------------------------------------ Push-T byte for byte
@pytest.mark.parametrize("task", [None, "pusht"])
def test_pusht_export_is_byte_identical_to_before_the_task_interface(task):
    """Every file of a Push-T export (PNG and video) has the sha256 that the code before export took a task
    (dc2fca9) wrote for the same buffer: tests/golden/make_lerobot_golden.py made the golden file there. Any
    changed byte (a feature's name or order, the fps, a timestamp, the task string, a column, a statistic)
    fails. The parquet, PNG and mp4 bytes also depend on pyarrow, Pillow and PyAV: under other versions than
    the golden's only the JSON files are compared, and the test says so by skipping the rest."""
    want = json.loads(GOLDEN.read_text())
    got = golden.digests(None if task is None else get_task(task))
    assert {k: sorted(v) for k, v in got.items()} == {k: sorted(v) for k, v in want["digests"].items()}
    for kind, files in want["digests"].items():
        for rel in files:
            if rel.endswith(".json"):
                assert got[kind][rel] == files[rel], f"{kind}: {rel}"
    if golden.library_versions() != want["versions"]:
        pytest.skip(f"library versions {golden.library_versions()} differ from the golden's {want['versions']}: "
                    "JSON files compared, parquet/mp4 bytes not")
    assert got == want["digests"]


def test_the_golden_check_can_fail(monkeypatch):
    """A one-character change of Push-T's task string changes the digests the check compares."""
    import bcbench.data.lerobot_format as fmt

    monkeypatch.setattr(fmt, "PUSHT", dataclasses.replace(fmt.PUSHT, text=TASK.rstrip(".")))
    assert golden.digests()["png"] != json.loads(GOLDEN.read_text())["digests"]["png"]


# ------------------------------------------------------------------------------------ any task
def test_features_rate_names_and_task_string_come_from_the_task(case, tmp_path):
    task, buf = case
    out = Path(export_lerobot(buf, tmp_path / "lr", task=task)["path"])
    info = json.loads((out / "meta" / "info.json").read_text())
    f = info["features"]
    pusht = task.family == "pusht"
    assert info["fps"] == task.control_hz and type(info["fps"]) is (int if task.control_hz.is_integer() else float)
    assert f["observation.image"]["shape"] == list(buf.images.shape[1:])
    assert f["observation.state"]["shape"] == [task.state_dim] and f["action"]["shape"] == [task.action_dim]
    names = (["x", "y"], ["x", "y"]) if pusht else (list(task.state_names), list(task.action_names))
    assert (f["observation.state"]["names"]["motors"], f["action"]["names"]["motors"]) == names
    bcbench = sorted(k for k in f if k.startswith("bcbench."))
    assert bcbench == (["bcbench.block_pose", "bcbench.keypoint", "bcbench.n_contacts"] if pusht else [])
    text = pq.read_table(out / "meta" / "tasks.parquet").column("task").to_pylist()
    assert text == [TASK if pusht else "Task."] and task_text(get_task("pusht")) == TASK
    data = pq.read_table(out / DATA_FILE)
    assert sorted(data.column_names) == sorted(f)
    frame = data.column("frame_index").to_numpy()
    assert np.array_equal(data.column("timestamp").to_numpy(), (frame / info["fps"]).astype(np.float32))
    stats = json.loads((out / "meta" / "stats.json").read_text())
    assert len(stats["observation.state"]["mean"]) == task.state_dim


def test_export_then_import_gives_the_buffer_back(case, tmp_path):
    task, buf = case
    back = import_lerobot(export_lerobot(buf, tmp_path / "lr", task=task)["path"], task=task)
    for key in ("state", "action", "images", "episode_ends", "keypoint", "n_contacts"):
        a, b = getattr(buf, key), getattr(back, key)
        assert (a is None and b is None) or (a.dtype == b.dtype and np.array_equal(a, b)), key
    assert back.missing == ()


@pytest.mark.parametrize("name", ["fake4", "fake7-64px-12.5hz"])
def test_video_export_of_another_task_is_aligned(name, tmp_path):
    task, buf = CASES[name]()
    back = import_lerobot(export_lerobot(buf, tmp_path / "v", video=True, task=task)["path"], task=task)
    assert np.array_equal(back.state, buf.state) and np.array_equal(back.episode_ends, buf.episode_ends)
    assert back.images.shape == buf.images.shape  # every row found its frame by timestamp, at the task's rate


def test_state_beyond_the_proprioception_travels_in_state_extra(tmp_path):
    task, buf = fake_task(), fake_buffer(state=6)
    out = export_lerobot(buf, tmp_path / "lr", task=task)["path"]
    assert json.loads((Path(out) / "meta" / "info.json").read_text())["features"]["bcbench.state_extra"]["shape"] == [2]
    assert np.array_equal(import_lerobot(out, task=task).state, buf.state)


def test_a_pusht_buffer_without_keypoints_exports_without_them(tmp_path):
    buf = dataclasses.replace(pusht_buffer(), keypoint=None, n_contacts=None)
    out = Path(export_lerobot(buf, tmp_path / "lr")["path"])
    features = json.loads((out / "meta" / "info.json").read_text())["features"]
    assert "bcbench.block_pose" in features and "bcbench.keypoint" not in features
    back = import_lerobot(out)
    assert back.missing == ("keypoint", "n_contacts") and np.array_equal(back.state, buf.state)


@pytest.mark.parametrize("exported_as, read_as, message", [
    ("fake4", "pusht", "'observation.state' has shape [4], expected [2]"),
    ("pusht", "fake4", "'observation.state' has shape [2], expected [4]"),
    ("fake4", "fake4-40hz", "recorded at 80 fps; task fake/task runs at 40"),
    ("fake4", "fake4-64px", "expected an image or video of shape [64, 64, 3]"),
])
def test_import_checks_the_dataset_against_the_task(exported_as, read_as, message, tmp_path):
    tasks = {"pusht": get_task("pusht"), "fake4": fake_task(), "fake4-40hz": fake_task(hz=40.0),
             "fake4-64px": fake_task(image_size=64)}
    buf = pusht_buffer() if exported_as == "pusht" else fake_buffer()
    out = export_lerobot(buf, tmp_path / "lr", task=tasks[exported_as])["path"]
    with pytest.raises(DatasetError) as e:
        import_lerobot(out, task=tasks[read_as])
    assert message in str(e.value) and "\n" not in str(e.value)


# ------------------------------------------------------------------------------------ the CLI
@pytest.fixture
def with_fake_task(monkeypatch):
    import bcbench.tasks as tasks

    task, real = fake_task(), tasks.get_task
    monkeypatch.setattr(tasks, "get_task", lambda name=None: task if name == task.name else real(name))
    return task


def test_cli_exports_and_summarises_another_tasks_demonstrations(with_fake_task, tmp_path, capsys):
    assert main(["data", "info", "--task", "fake/task", "--no-images"]) == 0
    assert f"episodes {len(LENGTHS)}, steps {sum(LENGTHS)}" in capsys.readouterr().out
    assert main(["data", "export", "--to", "lerobot", str(tmp_path / "lr"), "--task", "fake/task"]) == 0
    assert "wrote LeRobot v3.0 dataset" in capsys.readouterr().out
    back = import_lerobot(tmp_path / "lr", task=with_fake_task)
    assert np.array_equal(back.state, fake_buffer().state) and np.array_equal(back.images, fake_buffer().images)
    # the zarr writer knows Push-T's layout only: an import of another task's dataset says so in one line
    code = main(["data", "import", "--from", "lerobot", str(tmp_path / "lr"), "--task", "fake/task",
                 "--out", str(tmp_path / "o.zarr")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "Push-T's replay-buffer layout only" in err, err
    assert not (tmp_path / "o.zarr").exists()


@pytest.mark.parametrize("argv", [
    ["data", "export", "--to", "lerobot", "DEST", "--task", "nope"], ["data", "info", "--task", "nope"],
    ["data", "import", "--from", "lerobot", "SRC", "--out", "O", "--task", "nope"],
])
def test_an_unknown_task_is_one_line_exit_2(argv, tmp_path, capsys):
    argv = [str(tmp_path / a) if a in ("DEST", "SRC", "O") else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "unknown task 'nope'" in err, err
    assert not (tmp_path / "DEST").exists()
