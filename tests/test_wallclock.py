"""The delay model checked in wall-clock time: `bcbench serve` and `bcbench realtime --wall-clock`.

Tolerances on measured times are stated where they are used and are generous: the machine running the tests may be
busy (a study beside them on 2 cores), and none of these is a speed goal.
"""

from __future__ import annotations

import threading
from pathlib import Path
from statistics import median

import msgpack
import numpy as np
import pytest
import zmq

from bcbench.analysis.wallclock import check_pair, comparison_lines, wallclock_comparison
from bcbench.cli.main import main
from bcbench.cli.parser import build_parser
from bcbench.cli.wallclock import SpawnedServer
from bcbench.errors import BCBenchError
from bcbench.evaluation.config import WallClockConfig
from bcbench.evaluation.evaluate import EvalConfig, evaluate
from bcbench.evaluation.latency_sources import steps_for
from bcbench.evaluation.serve import PolicyServer, serve
from bcbench.evaluation.wallclock import PolicyClient, run_wallclock
from bcbench.evaluation.wire import check_address, decode, encode
from bcbench.utils.io import read_json
from tests.fake_policies import Sleepy, Toward

SLEEP_MS = 250  # d = 3 at 10 Hz whenever transport and scheduling add less than 50 ms to the call


class Chase(Sleepy):
    """Sleeps, then plans a path that depends on the newest observation (its agent position), so an action
    executed at the wrong step changes the episode: what the equality with the simulated controller checks."""

    name = "chase"

    def predict_action_chunk(self, obs):
        super().predict_action_chunk(obs)  # the sleep
        pos = np.asarray(obs["agent_pos"], dtype=np.float64)[:, -1]  # (B, 2)
        phi = pos[:, :1] / 40.0 + pos[:, 1:] / 70.0
        k = np.arange(1, 17)[None, :, None]
        step = np.concatenate([np.cos(phi), np.sin(phi)], axis=1)[:, None, :]
        return np.clip(pos[:, None, :] + 12.0 * k * step, 20, 492).astype(np.float32)


def one_line(text: str) -> bool:
    return len(text.strip().splitlines()) == 1


@pytest.fixture
def thread_server(tmp_path):
    """A policy server in a thread of this process on an ipc:// endpoint (local by construction)."""
    servers, done = [], threading.Event()

    def start(policy) -> str:
        address = f"ipc://{tmp_path}/policy-{len(servers)}"
        t = threading.Thread(target=serve, args=(policy, address, {}, None, done), daemon=True)
        t.start()
        servers.append(t)
        return address

    yield start
    done.set()
    for t in servers:
        t.join(timeout=5)


def test_a_wall_clock_run_records_the_known_delay_and_never_blocks_the_simulator(tmp_path, capsys):
    """The real thing: `bcbench serve` started as another process on a free loopback port, a policy that takes
    250 ms a call. Every call is measured at 250-400 ms and (nearly all) d = 3; control steps keep their 100 ms
    period while a call is out (a client that waited for the policy would show periods of 250 ms and more); then
    the simulated twin and the comparison are written."""
    out = tmp_path / "wc"
    code = main(["realtime", "--wall-clock", "--policy", "tests.fake_policies:sleepy", "--policy-arg",
                 f"ms={SLEEP_MS}", "--episodes", "1", "--max-steps", "30", "--out", str(out), "--quiet"])
    assert code == 0, capsys.readouterr().err
    record = read_json(out / "wallclock.json")
    assert record["type"] == "wallclock" and record["server"]["spawned"]
    assert record["policy"]["sleep_ms"] == SLEEP_MS and record["git_commit"] and record["hardware"]["cpu_model"]
    s = record["summary"]
    calls = record["episodes"][0]["calls"]
    assert len(calls) >= 5 and s["delays"]["calls"] == len(calls)  # 30 steps, a request every 5
    # sleep + the round trip: under 100 ms on a quiet machine, under 150 beside a test suite on the same 2 cores
    # (one call of a suite run took 107 ms more); d = 3 or 4 either way, as checked below. A server process the
    # suite starves can answer one call later still (seen: 506 ms, make test on a 2-core AMD EPYC): such a call must
    # then be seen as the longer delay it was (d >= 5 at 100 ms steps), never hidden
    assert all(c["delay_s"] >= 0.25 for c in calls), [c["delay_s"] for c in calls]
    # exact for every call: sent after step r started and taken before step r + d started, so its seconds fit in the
    # d recorded periods between them (period j runs from step j's start to step j + 1's)
    ep = record["episodes"][0]
    span_ms = [sum(ep["period_ms"][c["request_step"]:c["request_step"] + c["delay_steps"]]) for c in calls]
    assert all(c["delay_s"] * 1e3 <= m + 1e-6 for c, m in zip(calls, span_ms, strict=True)), (calls, span_ms)
    # a slow call is never hidden: either it counts as more steps, or this process's own clock slipped while it was
    # out (CI, make test on 2 cores: a 408 ms call at d = 3, a step in its span 206 ms late), which the record shows
    # as an overrun in its span and the periods that hold its seconds (checked above)
    overran = {o["step"] for o in ep["overruns"]}
    slow = [c for c in calls if c["delay_s"] >= 0.4]
    near = {c["id"]: set(range(c["request_step"] - 1, c["request_step"] + c["delay_steps"] + 1)) for c in calls}
    assert all(c["delay_steps"] >= 4 or overran & near[c["id"]] for c in slow), (slow, ep["overruns"])
    assert s["delays"]["median_steps"] == 3 and s["simulated_delay"] == 3
    # the threshold learnt from the calls: each request's D is the warm-up's d before any call is measured, then the
    # median d (rounded up) of the calls answered before it, the last 20. Replayed from the record rather than read
    # as "3 nearly always": one call at d = 4 early makes D = 4 for the next (CI: plan {3: 3, 4: 4} over 7 calls)
    first = max(1, steps_for(median(s["warmup_ms"]) / 1e3))
    seen = [c["delay_steps"] for c in calls]
    expected = [max(1, int(np.ceil(np.median(seen[max(0, i - 20):i])))) if i else first for i in range(len(calls))]
    assert [c["plan_delay"] for c in calls] == expected, ([c["plan_delay"] for c in calls], expected, s["warmup_ms"])
    assert first in (3, 4), s["warmup_ms"]  # a 250 ms call and its round trip: d = 3 (4 on a busy machine)
    # d = 3 or 4, unless a step near the call overran its period: the clock then slips (the next period starts when
    # that step ends), so fewer steps pass while the call is out (seen beside a suite and a training on 2 cores: d = 2
    # for a 0.25-0.4 s call); the record shows the overrun
    odd = [c for c in calls if c["delay_steps"] not in (3, 4) and c not in slow]
    assert all(overran & near[c["id"]] for c in odd), (odd, sorted(overran))
    assert len(odd) + len(slow) <= 1, (odd, slow)
    assert all(c["compute_ms"] >= SLEEP_MS for c in calls)
    assert record["episodes"][0]["length"] == 30
    # the world never waits: 100 ms periods while the policy computes (tolerance 15 ms median). A client that waited
    # for the policy would show, on every call, a step of at least the call's 250 ms and a period after it as long.
    # The CPU shared with the rest of a parallel suite on 2 cores can stretch one period on its own: in CI one
    # simulator step took 143 ms and the next started 134 ms late (a 277 ms period). So a period of 250 ms or more
    # is allowed once, only right after a step recorded as overrun whose own work was shorter than a call
    busy = ep["busy_period_ms"]
    assert len(busy) >= 2 * len(calls)
    assert abs(np.median(busy) - 100) < 15, busy
    step_ms_of_overrun = {o["step"]: o["step_ms"] for o in ep["overruns"]}
    long_after = [i for i, m in enumerate(ep["period_ms"]) if m >= SLEEP_MS]  # period i ends at step i + 1's start
    assert len(long_after) <= 1, [ep["period_ms"][i] for i in long_after]
    assert all(step_ms_of_overrun.get(i, SLEEP_MS) < SLEEP_MS for i in long_after), (long_after, ep["overruns"])
    printed = capsys.readouterr().out
    assert "median 3 steps" in printed and "histogram {'3'" in printed
    # its simulated twin, async at d = 3 on the same seed: this policy's target is fixed, so the scores are equal
    twin = read_json(out / "simulated-async-d3.json")
    assert twin["eval_config"]["latency_ms"] == 300
    assert twin["episodes"][0]["seed"] == record["episodes"][0]["seed"]
    comparison = read_json(out / "comparison.json")
    assert comparison["d"] == 3 and comparison["diff"] == 0 and "difference +0.000" in printed


def test_the_wall_clock_loop_executes_what_the_simulated_controller_does(thread_server):
    """When every call takes the d it was planned for and no step overruns, the wall-clock episode and the
    simulated async episode at that d are the same episode (the same final state, exactly): the loop's
    timing rules (threshold, the d skipped actions, the execution horizon, the hold) are the controller's."""
    cfg = WallClockConfig(episodes=3, max_steps=30, plan_delay=2, warmup_calls=1, execution_horizon=4)
    sim = evaluate(Chase(150), EvalConfig(episodes=3, max_steps=30, execution="async", latency_ms=200,
                                          execution_horizon=4, workers=1), progress=False)
    for _ in range(3):  # a busy machine (a suite beside a training on 2 cores) can spoil every episode of a try
        client = PolicyClient(thread_server(Chase(150)))  # d = 2 when transport adds under 50 ms
        record = run_wallclock(client, cfg, progress=False)
        client.close()
        clean = [e for e in record["episodes"]
                 if not e["overruns"] and all(c["delay_steps"] == 2 for c in e["calls"])]
        if clean:
            break
    assert clean, f"no episode had every call at d = 2 in 3 tries (too busy a machine): {record['summary']}"
    for e in clean:
        twin = sim["episodes"][e["episode"]]
        assert twin["seed"] == e["seed"] and twin["length"] == e["length"]
        assert e["final_state"] == twin["final_state"] and e["score"] == twin["score"]  # exactly


def test_an_overrun_is_recorded_not_hidden(thread_server):
    """A control period shorter than a simulator step: every step overruns, and the record says by how much."""
    client = PolicyClient(thread_server(Toward()))
    cfg = WallClockConfig(episodes=1, max_steps=10, plan_delay=1, warmup_calls=1, control_dt_s=1e-4)
    record = run_wallclock(client, cfg, progress=False)
    client.close()
    s = record["summary"]
    assert s["overruns"] == 10 and s["slip_ms"] > 0
    assert all(o["step_ms"] > 0.1 for o in record["episodes"][0]["overruns"])


def _args(*extra: str):
    return build_parser().parse_args(["realtime", "--wall-clock", "--policy", "tests.fake_policies:good", *extra])


def test_the_server_refuses_malformed_requests_in_one_line_and_keeps_serving(tmp_path):
    """A `bcbench serve` process: each malformed request gets an error answer (one line, naming the request's id
    where it had one), logged in one line; a good request after them is answered."""
    server = SpawnedServer(_args(), tmp_path / "server.log")
    ctx = zmq.Context.instance()
    sock = ctx.socket(zmq.REQ)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVTIMEO, 30_000)
    sock.connect(server.address)
    good_obs = {"image": np.zeros((2, 96, 96, 3), np.uint8), "agent_pos": np.full((2, 2), 100.0, np.float32)}
    bad = [
        b"\xc1 not msgpack",
        msgpack.packb([1, 2, 3]),
        encode({"type": "teleport", "id": 1}),
        encode({"type": "predict"}),
        encode({"type": "predict", "id": 2}),
        encode({"type": "predict", "id": 3, "obs": {**good_obs, "image": np.zeros((2, 96, 96, 3), np.float32)}}),
        encode({"type": "predict", "id": 4, "obs": {**good_obs, "agent_pos": np.zeros((3, 2), np.float32)}}),
        encode({"type": "predict", "id": 5, "obs": {**good_obs, "agent_pos": np.full((2, 2), np.nan)}}),
        encode({"type": "predict", "id": 6, "obs": {"image": {"dtype": "uint8", "shape": [2, 96, 96, 3],
                                                              "data": b"short"}, "agent_pos": good_obs["agent_pos"]}}),
        encode({"type": "predict", "id": 7, "obs": good_obs, "seed": -1}),
    ]
    try:
        for raw in bad:
            sock.send(raw)
            answer = decode(sock.recv())
            assert answer["type"] == "error" and one_line(answer["error"]), answer
        sock.send(bad[4])
        assert decode(sock.recv())["id"] == 2  # the error names the request it refuses
        sock.send(encode({"type": "predict", "id": 8, "obs": good_obs, "sent_at": 1.5, "seed": 100000, "first": True}))
        answer = decode(sock.recv())
        assert answer["type"] == "actions" and answer["id"] == 8 and answer["request_sent_at"] == 1.5
        assert answer["actions"]["shape"] == [16, 2] and answer["compute_ms"] >= 0
        assert answer["received_at"] <= answer["sent_at"]
        sock.send(encode({"type": "ping", "id": 9}))
        assert decode(sock.recv())["type"] == "pong"
        sock.send(encode({"type": "describe", "id": 10}))
        d = decode(sock.recv())
        assert d["name"] == "toward" and d["pred_horizon"] == 16 and d["policy"]["name"] == "toward"
    finally:
        sock.close()
        server.stop()
    refusals = [line for line in Path(server.log_path).read_text().splitlines() if "refused" in line]
    assert len(refusals) == len(bad) + 1


def test_a_policy_that_breaks_its_contract_is_an_error_answer_not_a_dead_server():
    class Broken(Toward):
        def predict_action_chunk(self, obs):
            return np.zeros((1, 8, 2), np.float32)

    server = PolicyServer(Broken())
    obs = {"image": np.zeros((2, 96, 96, 3), np.uint8), "agent_pos": np.zeros((2, 2), np.float32)}
    answer = server.handle(encode({"type": "predict", "id": 0, "obs": obs}))
    assert answer["type"] == "error" and "shape" in answer["error"] and one_line(answer["error"])
    assert server.handle(encode({"type": "ping", "id": 1}))["type"] == "pong"


@pytest.mark.parametrize("argv", [
    ["serve", "--policy", "tests.fake_policies:good", "--bind", "tcp://0.0.0.0:5555"],
    ["serve", "--policy", "tests.fake_policies:good", "--bind", "tcp://192.168.1.20:5555"],
    ["serve", "--policy", "tests.fake_policies:good", "--bind", "tcp://*:5555"],
    ["realtime", "--wall-clock", "--server", "tcp://10.1.2.3:5555"],
    ["realtime", "--wall-clock", "--policy", "tests.fake_policies:good", "--measured"],
    ["realtime", "--wall-clock", "--policy", "tests.fake_policies:good", "--delays", "0", "4"],
    ["realtime", "--wall-clock"],
])
def test_a_non_loopback_address_or_a_wrong_option_is_refused_in_one_line(argv, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert one_line(err) and err.startswith("bcbench: error:"), err


def test_loopback_addresses():
    for ok in ("tcp://127.0.0.1:5555", "tcp://127.0.0.1:*", "tcp://localhost:1", "tcp://[::1]:5555", "ipc:///tmp/x"):
        assert check_address(ok, False) == ok
    for bad in ("tcp://0.0.0.0:5555", "tcp://eth0:5555", "tcp://10.0.0.1:80", "udp://127.0.0.1:5", "tcp://127.0.0.1"):
        with pytest.raises(BCBenchError):
            check_address(bad, False)
    assert check_address("tcp://0.0.0.0:5555", True) == "tcp://0.0.0.0:5555"  # --allow-remote
    with pytest.raises(BCBenchError):
        WallClockConfig(plan_delay=0)


def _records(wall_scores, sim_scores, d=3, histogram=None):
    wall = {"type": "wallclock", "policy": {"name": "p", "weights_sha256": "ab"},
            "wallclock_config": {"execution_horizon": None, "max_steps": 300},
            "summary": {"simulated_delay": d, "plan_delay": {str(d): 10}, "overruns": 0, "steps": 3000,
                        "delays": {"calls": 10, "median_steps": d, "median_s": 0.25, "p90_steps": d, "max_steps": d,
                                   "histogram": histogram or {str(d): 10}}},
            "episodes": [{"seed": 100 + i, "score": s} for i, s in enumerate(wall_scores)]}
    sim = {"type": "evaluation", "policy": {"name": "p", "weights_sha256": "ab"},
           "eval_config": {"execution": "async", "latency_ms": d * 100.0, "execution_horizon": None, "max_steps": 300},
           "episodes": [{"seed": 100 + i, "score": s} for i, s in enumerate(sim_scores)]}
    return wall, sim


def test_the_comparison_pairs_on_episode_seeds_and_checks_the_rule():
    wall, sim = _records([0.9, 0.5, 0.7, 1.0], [0.8, 0.5, 0.6, 0.9])
    c = wallclock_comparison(wall, sim)
    assert c["d"] == 3 and c["n"] == 4 and c["diff"] == pytest.approx(0.075)
    assert c["ci"][0] <= 0.075 <= c["ci"][1] and c["share_at_d"] == 1
    assert "a difference is noise" in comparison_lines(c)[-1]
    wall2, _ = _records([0.9] * 4, [0.8] * 4, histogram={"3": 6, "4": 4})
    assert "40% of the calls took another d" in comparison_lines(wallclock_comparison(wall2, sim))[-1]
    _, sim_d2 = _records([0.9] * 4, [0.8] * 4, d=2)
    with pytest.raises(BCBenchError, match="at d = 2; the wall-clock run pairs with async at d = 3"):
        check_pair(wall, sim_d2)
    sim["policy"]["weights_sha256"] = "cd"
    with pytest.raises(BCBenchError, match="weights_sha256"):
        check_pair(wall, sim)


def test_arrays_cross_the_wire_exactly():
    a = np.arange(24, dtype=np.float32).reshape(2, 3, 4) / 7
    back = decode(encode({"x": a}))["x"]
    assert back["dtype"] == "float32" and back["shape"] == [2, 3, 4]
    np.testing.assert_array_equal(np.frombuffer(back["data"], np.float32).reshape(2, 3, 4), a)
