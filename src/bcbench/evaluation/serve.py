"""`bcbench serve`: a policy server, the program a robot's computer would run beside its controller.

It holds one `ChunkPolicy` (loaded as `bcbench eval` loads it: a trained run in its inference mode, a baseline, a
plug-in or module:factory) and answers requests on a ZeroMQ REP socket, one at a time, in the format of
`bcbench.evaluation.wire` (predict, describe, ping). A malformed request is answered with an error in one line
(and logged in one line on stderr) and the server goes on: one bad client must not take the robot's policy down.
Each predict call runs the policy at batch 1; a request that names its episode's seed gets that episode's noise
stream, (noise seed, episode seed), the one `bcbench eval` gives it, so a wall-clock episode and its simulated
twin draw the same noise call for call (their observations, not their noise, differ).
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from collections import OrderedDict
from typing import Any

import numpy as np
import torch
import zmq

from bcbench.errors import BCBenchError
from bcbench.evaluation.controller import episode_generator
from bcbench.evaluation.wire import WireError, check_request, decode, encode, error, observation, request_id
from bcbench.interface import ChunkPolicy, SeededPolicy

KEPT_STREAMS = 8  # episodes whose noise streams the server keeps (a client runs one at a time)
LISTENING = "bcbench serve: listening on "  # the line a client that started the server waits for (stdout)


class PolicyServer:
    """Answers wire requests with one policy (the transport is `serve`'s; this part is testable without it)."""

    def __init__(self, policy: ChunkPolicy, server_info: dict[str, Any] | None = None) -> None:
        self.policy, self.server_info = policy, server_info or {}
        self._streams: OrderedDict[int, torch.Generator] = OrderedDict()
        self.served = self.refused = 0

    def handle(self, raw: bytes) -> dict[str, Any]:
        """The answer to one raw request; never raises for a malformed one (an error answer instead)."""
        received = time.time()
        rid = None
        try:
            message = decode(raw)
            rid = request_id(message)
            kind = check_request(message)
            answer = getattr(self, f"_{kind}")(message)
        except WireError as exc:
            self.refused += 1
            print(f"bcbench serve: refused request {rid}: {exc}", file=sys.stderr, flush=True)
            return error(rid, str(exc))
        except Exception as exc:
            self.refused += 1
            first = (str(exc).strip().splitlines() or [""])[0]
            print(f"bcbench serve: request {rid} failed: {type(exc).__name__}: {first}", file=sys.stderr, flush=True)
            return error(rid, f"the policy failed: {type(exc).__name__}: {first}")
        self.served += 1
        answer.update(id=rid, received_at=received, sent_at=time.time())
        if "sent_at" in message:
            answer["request_sent_at"] = message["sent_at"]
        return answer

    def _ping(self, message: dict[str, Any]) -> dict[str, Any]:
        return {"type": "pong"}

    def _describe(self, message: dict[str, Any]) -> dict[str, Any]:
        p = self.policy
        return {"type": "describe", "policy": p.describe(), "name": p.name, "obs_horizon": int(p.obs_horizon),
                "pred_horizon": int(p.pred_horizon), "action_horizon": int(p.action_horizon),
                "chunk_start": int(p.chunk_start), "server": self.server_info}

    def _generator(self, message: dict[str, Any]) -> torch.Generator | None:
        seed = message.get("seed")
        if seed is None:
            return None
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise WireError("seed must be a whole number >= 0")
        if message.get("first") or seed not in self._streams:
            noise_seed = self.policy.noise_seed if isinstance(self.policy, SeededPolicy) else 0
            self._streams[seed] = episode_generator(noise_seed, seed)
            while len(self._streams) > KEPT_STREAMS:
                self._streams.popitem(last=False)
        self._streams.move_to_end(seed)
        return self._streams[seed]

    def _predict(self, message: dict[str, Any]) -> dict[str, Any]:
        obs = observation(message, int(self.policy.obs_horizon))
        batch: dict[str, Any] = {k: v[None] for k, v in obs.items()}
        gen = self._generator(message)
        if gen is not None:
            batch["generators"] = [gen]
        t0 = time.perf_counter()
        chunk = np.asarray(self.policy.predict_action_chunk(batch), dtype=np.float32)
        compute_ms = (time.perf_counter() - t0) * 1e3
        want = (1, int(self.policy.pred_horizon), 2)
        if chunk.shape != want or not np.isfinite(chunk).all():  # the policy's fault, said to the client in one line
            raise WireError(f"the policy returned a chunk of shape {chunk.shape} (or non-finite), expected {want}")
        return {"type": "actions", "actions": chunk[0], "compute_ms": compute_ms}


def serve(policy: ChunkPolicy, bind: str, server_info: dict[str, Any] | None = None,
          max_requests: int | None = None, stop_event: threading.Event | None = None) -> PolicyServer:
    """Serve `policy` on `bind` (checked by the caller: loopback unless allowed) until SIGTERM / SIGINT (or
    `max_requests` answers, or `stop_event`); prints LISTENING + the endpoint once bound (a `*` port resolved)."""
    ctx = zmq.Context.instance()
    sock = ctx.socket(zmq.REP)
    sock.setsockopt(zmq.LINGER, 0)
    try:
        sock.bind(bind)
    except zmq.ZMQError as exc:
        sock.close()
        raise BCBenchError(f"cannot bind {bind}: {exc}") from None
    endpoint = sock.getsockopt_string(zmq.LAST_ENDPOINT)
    server = PolicyServer(policy, {**(server_info or {}), "endpoint": endpoint})
    stop: list[int] = []
    main_thread = threading.current_thread() is threading.main_thread()  # a test may serve from a thread
    previous = signal.signal(signal.SIGTERM, lambda *a: stop.append(1)) if main_thread else None
    print(f"{LISTENING}{endpoint}", flush=True)
    try:
        while not stop and not (stop_event and stop_event.is_set()) and (
                max_requests is None or server.served + server.refused < max_requests):
            if not sock.poll(200):  # wake up now and then to notice SIGTERM
                continue
            frames = sock.recv_multipart()
            answer = server.handle(frames[0]) if len(frames) == 1 else error(None, "one frame per message")
            try:
                payload = encode(answer)
            except Exception as exc:
                payload = encode(error(answer.get("id"), f"the answer could not be encoded: {type(exc).__name__}"))
            sock.send(payload)
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, previous)
        sock.close()
    return server
