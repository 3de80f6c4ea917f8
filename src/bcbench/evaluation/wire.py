"""The policy server's wire format (`bcbench serve`, `bcbench realtime --wall-clock`): ZeroMQ, msgpack, numpy.

Transport: a ZeroMQ REP socket on the server (one request answered at a time, as a robot's policy computer serves
its one robot); a client connects a DEALER (or REQ) socket. A DEALER sends an empty delimiter frame, then the
message: it may keep sending while nothing came back, so a client whose world never waits can drop a late answer
instead of blocking on it. Every message is one msgpack map. An array is a map {"dtype": "uint8", "shape": [2,
96, 96, 3], "data": <bytes, C order>} (little-endian dtypes: uint8, float32, float64), readable in any language.

Requests (`type`):
- predict: {"type": "predict", "id": int, "obs": {"image": uint8 (To, 96, 96, 3), "agent_pos": float (To, 2)
  pixels}, "sent_at": float (the client's clock, seconds), optional "seed": int (the episode's seed: its noise
  stream is (the policy's noise seed, seed), as `bcbench eval` draws it), optional "first": bool (the episode's
  first call: its stream restarts)}. The keys of `obs` are those of bcbench.interface's Observation, one window
  (no batch axis), oldest frame first.
  -> {"type": "actions", "id", "actions": float32 (pred_horizon, 2) pixels (index chunk_start is the action for the
  step of the newest frame), "compute_ms": the policy call alone, "received_at" and "sent_at" (the server's
  clock when the request was read and the answer sent, seconds since the epoch), "request_sent_at" (the
  request's own sent_at, echoed)}.
- describe: {"type": "describe", "id"} -> {"type": "describe", "id", "policy": the policy's describe() (a trained
  run's includes weights_sha256), "name", "obs_horizon", "pred_horizon", "action_horizon", "chunk_start",
  "server": {...}}.
- ping: {"type": "ping", "id", "sent_at"} -> {"type": "pong", "id", "received_at", "sent_at", "request_sent_at"}.
Anything malformed -> {"type": "error", "id": the request's id or None, "error": one line}; the server goes on.

Clocks: "sent_at" and "received_at" are time.time() (the epoch clock, which NTP keeps close across machines); on
one machine the client measures a call's delay on its own monotonic clock and needs none of them.
"""

from __future__ import annotations

import ipaddress
import time
from typing import Any

import msgpack
import numpy as np

from bcbench.errors import BCBenchError

DTYPES = ("uint8", "float32", "float64")
REQUEST_TYPES = ("predict", "describe", "ping")
LOOPBACK_NAMES = ("localhost",)


class WireError(ValueError):
    """A malformed message, in one line (the server answers it as an error and goes on)."""


def _pack_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        if a.dtype.name not in DTYPES:
            a = a.astype(np.float64 if a.dtype.kind == "f" else np.float32)
        return {"dtype": a.dtype.name, "shape": list(a.shape), "data": a.astype(a.dtype.newbyteorder("<")).tobytes()}
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot send a {type(obj).__name__}")


def encode(message: dict[str, Any]) -> bytes:
    """One message as msgpack bytes, numpy arrays as {"dtype", "shape", "data"} maps."""
    return msgpack.packb(message, default=_pack_default, use_bin_type=True)


def decode(raw: bytes) -> dict[str, Any]:
    """A message map from msgpack bytes (arrays stay maps until `array` reads them); WireError if it is not one."""
    try:
        message = msgpack.unpackb(raw, raw=False, strict_map_key=False)
    except Exception as exc:
        raise WireError(f"not a msgpack message ({type(exc).__name__})") from None
    if not isinstance(message, dict):
        raise WireError(f"a message is a msgpack map, got {type(message).__name__}")
    return message


def array(value: Any, what: str, dtypes: tuple[str, ...], shape: tuple[int | None, ...]) -> np.ndarray:
    """The numpy array of a {"dtype", "shape", "data"} map, checked against `dtypes` and `shape` (None: any size)."""
    if not isinstance(value, dict) or not {"dtype", "shape", "data"} <= set(value):
        raise WireError(f"{what} must be an array map with dtype, shape and data")
    dtype, dims, data = value["dtype"], value["shape"], value["data"]
    if dtype not in dtypes:
        raise WireError(f"{what} must be {' or '.join(dtypes)}, got {dtype!r}")
    if not isinstance(dims, list) or not all(isinstance(n, int) and n >= 0 for n in dims):
        raise WireError(f"{what}: shape must be a list of sizes")
    if len(dims) != len(shape) or any(w is not None and n != w for n, w in zip(dims, shape, strict=True)):
        want = "(" + ", ".join("any" if w is None else str(w) for w in shape) + ")"
        raise WireError(f"{what} must have shape {want}, got {tuple(dims)}")
    if not isinstance(data, bytes) or len(data) != int(np.prod(dims)) * np.dtype(dtype).itemsize:
        raise WireError(f"{what}: data must hold {int(np.prod(dims))} {dtype} values")
    return np.frombuffer(data, dtype=np.dtype(dtype).newbyteorder("<")).reshape(dims).astype(dtype)


def request_id(message: dict[str, Any]) -> int | None:
    """The request's id when it is a whole number (an error answer names it), else None."""
    rid = message.get("id")
    return rid if isinstance(rid, int) and not isinstance(rid, bool) else None


def check_request(message: dict[str, Any]) -> str:
    """The request's type once its common fields are well formed; WireError (one line) otherwise."""
    kind = message.get("type")
    if kind not in REQUEST_TYPES:
        raise WireError(f"unknown request type {kind!r} (known: {', '.join(REQUEST_TYPES)})")
    if request_id(message) is None:
        raise WireError("a request needs a whole-number id")
    if "sent_at" in message and not isinstance(message["sent_at"], int | float):
        raise WireError("sent_at must be a number (seconds)")
    return kind


def observation(message: dict[str, Any], obs_horizon: int) -> dict[str, np.ndarray]:
    """A predict request's observation window, checked: image uint8 (To, 96, 96, 3), agent_pos (To, 2) finite."""
    obs = message.get("obs")
    if not isinstance(obs, dict):
        raise WireError("predict needs obs: {image, agent_pos}")
    image = array(obs.get("image"), "obs.image", ("uint8",), (obs_horizon, 96, 96, 3))
    pos = array(obs.get("agent_pos"), "obs.agent_pos", ("float32", "float64"), (obs_horizon, 2))
    if not np.isfinite(pos).all():
        raise WireError("obs.agent_pos must be finite")
    return {"image": image, "agent_pos": pos.astype(np.float32)}


def error(rid: int | None, text: str) -> dict[str, Any]:
    """An error answer: the reason in one line."""
    return {"type": "error", "id": rid, "error": " ".join(str(text).split()), "sent_at": time.time()}


def check_address(address: str, allow_remote: bool, flag: str = "--bind") -> str:
    """`address` if it is a loopback ZeroMQ endpoint (tcp://127.x.x.x:PORT, tcp://[::1]:PORT, tcp://localhost:PORT,
    ipc://PATH) or `allow_remote`; else BCBenchError in one line. Why: a policy server answers anyone who can reach
    it, and bcbench's traffic stays on this machine unless its user says otherwise."""
    scheme, sep, rest = address.partition("://")
    if not sep or scheme not in ("tcp", "ipc") or not rest:
        raise BCBenchError(f"{flag} takes tcp://HOST:PORT or ipc://PATH, got '{address}'")
    if scheme == "ipc":
        return address
    host, colon, port = rest.rpartition(":")
    if not colon or not host or not (port == "*" or port.isdigit()):
        raise BCBenchError(f"{flag} takes tcp://HOST:PORT (PORT a number, or * for any free one), got '{address}'")
    if allow_remote:
        return address
    name = host.strip("[]")
    try:
        loopback = ipaddress.ip_address(name).is_loopback
    except ValueError:
        loopback = name in LOOPBACK_NAMES
    if not loopback:
        raise BCBenchError(f"{flag} {address} is not a loopback address: bcbench serves on this machine only "
                           "(127.0.0.1) unless --allow-remote")
    return address
