"""One seeded MetaWorld (v3) environment with a fast fixed camera: what `bcbench.tasks.spec.Episode` asks for.

MetaWorld 3.1.1 needs three things done by hand to be a benchmark environment (facts.md, and its source):
- Seeding: gymnasium's `reset(seed=)` is ignored; the object and goal come from `env.np_random` only when
  `seeded_rand_vec` is on and `_freeze_rand_vec` off, and `env.seed(s)` re-seeds it. We call `env.seed(seed)`
  before every reset, so every reset of an episode (and the same seed in any process) is the same start.
- Goal observability: the goal is zeroed in the 39-D observation (and clipped to 0 by the cached observation
  space) unless `_partially_observable` is False and the cache is dropped; the scripted experts need the goal.
- Rendering: out of the box a frame costs 120-140 ms on llvmpipe (4096^2 shadow maps, 4x multisampling). With
  multisampling, shadows and reflections off before the renderer is made, it costs about a tenth; the objects
  are where they were (tests/test_metaworld.py compares the two).
We render with our own `mujoco.Renderer`s (one at the policy's size, one at the video size) instead of
gymnasium's, so that the two sizes share one camera and one set of settings. The episodes of one task in one process
share them: a renderer's GL context and MjrContext (the model's meshes and textures on the GPU, or llvmpipe's memory)
cost about 100-150 MB, and an evaluation keeps every episode of a worker alive at once (100 MetaWorld episodes on 2
workers held 15 GB with a renderer each). Each frame's scene is built from the episode's own model and data (MetaWorld
moves bodies in the model at reset), so a shared renderer draws the same pixels as an episode's own (tested).
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported: headless machines have no display

from typing import Any

import numpy as np

from bcbench.errors import BCBenchError
from bcbench.tasks.metaworld.table import IMAGE_SIZE, TASKS
from bcbench.tasks.spec import Obs

FLIPPED_CAMERAS = ("corner", "corner2", "corner3", "corner4")  # MetaWorld's corner views come out rotated 180°
VIDEO_SIZE = 256


def _import_metaworld() -> tuple[Any, Any]:
    """(mujoco, metaworld's v3 env classes), or one BCBenchError line saying what to install."""
    try:
        import mujoco
        from metaworld.env_dict import ALL_V3_ENVIRONMENTS
    except ModuleNotFoundError as exc:
        raise BCBenchError(f"MetaWorld cannot be imported ({exc}); install it with `pip install -e .[metaworld]` "
                           "(metaworld==3.1.1, mujoco==3.3.0)") from None
    except Exception as exc:  # mujoco loads its GL backend on import: a bad MUJOCO_GL, no libEGL/libOSMesa
        raise _cannot_render(exc) from None
    return mujoco, ALL_V3_ENVIRONMENTS


def _cannot_render(exc: Exception) -> BCBenchError:
    first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return BCBenchError(f"MetaWorld cannot render ({type(exc).__name__}: {first}; MUJOCO_GL="
                        f"{os.environ.get('MUJOCO_GL')}): set MUJOCO_GL=egl (libegl1) or MUJOCO_GL=osmesa "
                        "(install libosmesa6)")


def make_fast(model: Any) -> None:
    """Switch off what costs most and changes least at 96 px: multisampling, shadows, reflections.
    Must run before any renderer is made: the offscreen buffers are sized from `vis.quality` then."""
    model.vis.quality.offsamples = 0
    model.vis.quality.shadowsize = 0  # no shadow map to allocate (shadows are off below)
    model.light_castshadow[:] = 0
    model.mat_reflectance[:] = 0


_SHARED: dict[tuple[str, int, bool], list[Any]] = {}  # (task, size, fast) -> [renderer, episodes using it]


def _acquire(mujoco: Any, key: tuple[str, int, bool], model: Any) -> Any:
    """The process's renderer for (task, size, fast), made from `model` if none is live; one more user."""
    entry = _SHARED.get(key)
    if entry is None:
        entry = _SHARED[key] = [_renderer(mujoco, model, key[1], key[2]), 0]
    entry[1] += 1
    return entry[0]


def _release(key: tuple[str, int, bool]) -> None:
    """One user less; the last one frees the renderer (a process that makes episodes one at a time keeps none)."""
    entry = _SHARED[key]
    entry[1] -= 1
    if entry[1] == 0:
        del _SHARED[key]
        free_renderer(entry[0])


def _renderer(mujoco: Any, model: Any, size: int, fast: bool) -> Any:
    try:
        r = mujoco.Renderer(model, height=size, width=size)
    except Exception as exc:  # no EGL/OSMesa context, or a size above the model's offscreen buffer (640x480)
        raise _cannot_render(exc) from None
    if fast:
        r.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
        r.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
    return r


class MetaWorldEpisode:
    """A MetaWorld task at one seed: object and goal drawn from the seed, the goal observable, a fixed camera.

    obs = {"pixels": uint8 (image_size, image_size, 3), "agent_pos": float32 (S,)} with S the table's
    proprioception (hand xyz, gripper opening[, goal xyz]); `full_obs` is MetaWorld's 39-D observation
    (the scripted experts read it). reward is 1.0 once MetaWorld's info["success"] has held, else 0.0;
    terminated = success; progress = MetaWorld's shaped reward / 10 (its rewards lie in [0, 10]). Progress is
    MetaWorld's shaping, not a score: at the expert's success it reads 1.0 (door-open, peg-insert-side,
    assembly), 0.92 (drawer-open), 0.69 (pick-place), 0.03 (stick-pull, whose reward drops once the stick is in).
    """

    def __init__(self, name: str, seed: int, video_size: int | None = None, *, image_size: int = IMAGE_SIZE,
                 camera: str | None = None, fast: bool = True) -> None:
        if name not in TASKS:
            raise BCBenchError(f"unknown MetaWorld task '{name}' (choose {', '.join(TASKS)})")
        self.mujoco, envs = _import_metaworld()
        spec = TASKS[name]
        self.name, self.seed, self.image_size = name, int(seed), int(image_size)
        self.video_size = VIDEO_SIZE if video_size is None else int(video_size)
        self.camera: str = camera or spec["camera"]
        self._proprio = tuple(spec["proprio"])
        env = envs[spec["env"]]()  # no render_mode: our renderers below, not gymnasium's
        env._partially_observable = False
        env.__dict__.pop("sawyer_observation_space", None)  # the cached space would clip the goal to 0
        env._freeze_rand_vec = False
        env.seeded_rand_vec = True
        env._set_task_called = True
        self.env = env
        if fast:
            make_fast(env.model)
        self._fast = fast
        self._cam_id = env.model.camera(self.camera).id
        self._view = self.mujoco.MjvCamera()  # the task's fixed camera, as Renderer.update_scene(camera=id) sets it
        self._view.type, self._view.fixedcamid = self.mujoco.mjtCamera.mjCAMERA_FIXED, self._cam_id
        self._option = self.mujoco.MjvOption()  # the default visual options, as a Renderer's own
        self._renderers: dict[int, Any] = {}  # size -> the shared renderer this episode holds (_acquire)
        self._full_obs = np.zeros(39)
        self._succeeded = False
        self.frame(self.image_size)  # make the policy's renderer now: a machine that cannot render fails here

    # ------------------------------------------------------------------ rendering
    def frame(self, size: int) -> np.ndarray:
        """A uint8 (size, size, 3) frame from the task's camera, upright."""
        r = self._renderers.get(size)
        if r is None:
            r = self._renderers[size] = _acquire(self.mujoco, (self.name, size, self._fast), self.env.model)
        # the scene from this episode's own model and data (Renderer.update_scene would read the model it was made
        # from, another episode's when shared)
        self.mujoco.mjv_updateScene(self.env.model, self.env.data, self._option, None, self._view,
                                    self.mujoco.mjtCatBit.mjCAT_ALL.value, r.scene)
        img = r.render()  # (size, size, 3) uint8
        if self.camera in FLIPPED_CAMERAS:
            img = img[::-1, ::-1]
        return np.ascontiguousarray(img)

    def render(self) -> np.ndarray:
        return self.frame(self.video_size)

    # ------------------------------------------------------------------ episode
    @property
    def full_obs(self) -> np.ndarray:
        """MetaWorld's 39-D observation after the last reset/step: hand xyz, gripper, objects (14), the
        previous step's 18, goal xyz (observable here)."""
        return self._full_obs.copy()

    def world_state(self) -> list[float]:
        """What records keep: hand xyz, main object xyz, goal xyz (9 floats)."""
        o = self._full_obs
        return [float(v) for v in (*o[0:3], *o[4:7], *o[36:39])]

    def _obs(self) -> Obs:
        agent_pos = self._full_obs[list(self._proprio)].astype(np.float32)  # (S,)
        return {"pixels": self.frame(self.image_size), "agent_pos": agent_pos}

    def reset(self, seed: int | None = None) -> tuple[Obs, float, list[float]]:
        """The seed's start. `seed` moves this episode to another seed first: the generator reuses one env
        for many seeds, as making a renderer costs about 0.5 s."""
        if seed is not None:
            self.seed = int(seed)
        self.env.seed(self.seed)  # every reset is the seed's start (MetaWorld ignores reset(seed=))
        obs39, _ = self.env.reset()
        # MetaWorld's reset moves the goal site in the model after its last mj_forward, so the reset frame
        # would show the previous draw's goal marker (pick-place: 20 cm away) until the first step
        self.mujoco.mj_forward(self.env.model, self.env.data)
        self._full_obs = np.asarray(obs39, dtype=np.float64)
        self._succeeded = False
        reward, _ = self.env.evaluate_state(self._full_obs, np.zeros(4, dtype=np.float32))
        return self._obs(), _progress(reward), self.world_state()

    def step(self, action: np.ndarray) -> tuple[Obs, float, bool, float, list[float]]:
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(4), -1.0, 1.0)
        if self.env.curr_path_length >= self.env.max_path_length:
            raise BCBenchError(f"metaworld/{self.name}: MetaWorld allows at most {self.env.max_path_length} steps")
        obs39, reward, _, _, info = self.env.step(a)
        self._full_obs = np.asarray(obs39, dtype=np.float64)
        self._succeeded = self._succeeded or bool(info["success"])
        return (self._obs(), 1.0 if self._succeeded else 0.0, bool(info["success"]), _progress(reward),
                self.world_state())

    def close(self) -> None:
        """Release its renderers (the last episode using one frees it) and free the env (left to the garbage
        collector, EGL complains at exit)."""
        for size in self._renderers:
            _release((self.name, size, self._fast))
        self._renderers.clear()
        self.env.close()


def free_renderer(r: Any) -> None:
    """Close a `mujoco.Renderer` in its own GL context. `Renderer.close()` destroys the GL context first and then
    frees the MjrContext in whatever context is current: under OSMesa or GLFW another live renderer's, whose
    textures and buffers it deletes (that one then draws noise; under EGL no context is current by then).
    MuJoCo 3.3.0's attribute names."""
    if getattr(r, "_gl_context", None) is not None and getattr(r, "_mjr_context", None) is not None:
        r._gl_context.make_current()
        r._mjr_context.free()
        r._mjr_context = None
    r.close()


def _progress(reward: float) -> float:
    return float(np.clip(float(reward) / 10.0, 0.0, 1.0))
