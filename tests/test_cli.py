"""The command line: help everywhere, one-line errors, and an end-to-end smoke run."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from bcbench.cli.main import main

SUBCOMMANDS = [["data"], ["data", "fetch"], ["data", "info"], ["data", "replay"], ["eval"]]


def test_top_level_help_lists_subcommands(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for name in ("data", "eval"):
        assert name in out


@pytest.mark.parametrize("cmd", SUBCOMMANDS, ids=" ".join)
def test_every_subcommand_has_help(cmd, capsys):
    with pytest.raises(SystemExit) as exc:
        main([*cmd, "--help"])
    assert exc.value.code == 0
    assert "usage:" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv",
    [
        ["frobnicate"],
        ["eval", "--policy", "random", "--bogus"],
        ["eval", "--policy", "random", "--episodes", "0"],
        ["eval", "--policy", "random", "--episodes", "many"],
        ["data", "replay", "--workers", "-1"],
    ],
    ids=["unknown-command", "unknown-option", "zero-episodes", "not-a-number", "negative"],
)
def test_usage_errors_are_one_line(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "error" in err and "Traceback" not in err


@pytest.mark.parametrize(
    "argv, message",
    [
        (["data", "info", "--data", "/nonexistent/pusht.zarr"], "not found"),
        (["eval", "--policy", "random", "--video", "5", "--episodes", "2"], "--video"),
        (["eval", "--policy", "nope"], "unknown policy 'nope': not a registered policy, not an installed plug-in"),
        (["data", "fetch", "--from", "/nonexistent.zip", "--dest", "/tmp/bcbench-never"], "no such file"),
    ],
)
def test_bad_input_is_one_line(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err


def test_corrupt_dataset_is_one_line(synthetic_zarr, tmp_path, capsys):
    import shutil

    bad = tmp_path / "bad.zarr"
    shutil.copytree(synthetic_zarr, bad)
    (bad / "data" / "state" / "0.0").write_bytes(b"garbage")
    assert main(["data", "info", "--no-images", "--data", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "corrupt" in err


def test_data_info_and_fetch_from(synthetic_zarr, tmp_path, capsys):
    assert main(["data", "info", "--data", str(synthetic_zarr)]) == 0
    assert "episodes 3, steps 37" in capsys.readouterr().out
    dest = tmp_path / "d.zarr"
    assert main(["data", "fetch", "--from", str(synthetic_zarr), "--dest", str(dest), "--quiet"]) == 0
    assert "dataset ready" in capsys.readouterr().out and dest.is_dir()


def test_end_to_end_smoke(tmp_path):
    """The installed console script, as a user runs it."""
    exe = os.path.join(os.path.dirname(sys.executable), "bcbench")
    out = tmp_path / "run"
    proc = subprocess.run(
        [exe, "eval", "--policy", "scripted", "--episodes", "2", "--max-steps", "16", "--out", str(out), "--quiet"],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert "mean score" in proc.stdout
    result = json.loads((out / "eval.json").read_text())
    assert result["summary"]["n"] == 2 and result["policy"]["name"] == "scripted"


def test_data_replay_command(real_zarr, tmp_path, capsys):
    out = tmp_path / "replay.json"
    assert main(["data", "replay", "--data", str(real_zarr), "--episodes", "4", "--workers", "1", "--quiet",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "4/4 = 100.0%" in text and "demonstrators' score" in text
    assert json.loads(out.read_text())["exact_episodes"] == 4


def test_pretrained_only_for_policies_that_can_use_it(tmp_path, capsys):
    from bcbench.cli.main import main

    weights = tmp_path / "r18.pth"
    weights.write_bytes(b"x")
    assert main(["train", "--policy", "cnn_mlp", "--pretrained", str(weights), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--pretrained applies to" in err[0] and not (tmp_path / "r").exists()


def test_untested_library_versions_fail_clearly(monkeypatch):
    from bcbench.errors import BCBenchError
    from bcbench.utils import system

    monkeypatch.setitem(system.KNOWN_GOOD, "diffusers", ("0.0.1",))
    monkeypatch.delenv("BCBENCH_ALLOW_UNTESTED_VERSIONS", raising=False)
    with pytest.raises(BCBenchError, match="not a version bcbench was checked against"):
        system.require_known_version("diffusers")
    monkeypatch.setenv("BCBENCH_ALLOW_UNTESTED_VERSIONS", "1")
    system.require_known_version("diffusers")  # the escape hatch


def test_output_into_a_closed_pipe_is_no_error():
    """`bcbench ... | head` stops reading early: exit 0 and nothing on stderr, not a BrokenPipeError traceback."""
    p = subprocess.Popen([sys.executable, "-m", "bcbench.cli", "policies"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE)
    p.stdout.close()  # the reader is gone before the command writes
    err = p.stderr.read()
    assert p.wait() == 0 and err == b""


def test_no_pkg_resources_warning_where_setuptools_is_installed(tmp_path):
    """pygame (through gym-pusht) imports setuptools' pkg_resources where it exists, which warns that it is
    deprecated on every command (seen on a GPU image with setuptools installed): bcbench keeps that off stderr.
    A stand-in pkg_resources that warns as setuptools >= 67 does takes setuptools' place here."""
    (tmp_path / "pkg_resources.py").write_text(
        "import warnings\n"
        "warnings.warn('pkg_resources is deprecated as an API. See https://setuptools.pypa.io', UserWarning,"
        " stacklevel=2)\n"
        "def resource_stream(*a): raise NotImplementedError\n"
        "def resource_exists(*a): return False\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])}
    p = subprocess.run([sys.executable, "-m", "bcbench.cli", "policies"], capture_output=True, text=True, env=env,
                       timeout=120)
    assert p.returncode == 0 and p.stderr == "", p.stderr
