"""bcbench's MetaWorld tasks, as data (no MuJoCo import, so that `bcbench.tasks.task_names()` stays light).

Per task: MetaWorld's v3 env, the difficulty group (Seo et al., 2022, as 3D Diffusion Policy groups them), the
scripted expert (`metaworld.policies`), which dimensions of MetaWorld's 39-D observation the proprioception
holds, the episode cap and the camera. Every number below was measured with MetaWorld 3.1.1 / MuJoCo 3.3.0
(seeds 0-29, the goal observable, the expert's action clipped to [-1, 1], at most 500 steps):

    task             expert success  length median / max  cap   goal in proprio
    drawer-open      30/30           89 / 93              150   no: the goal is the drawer's open position
    door-open        28/30           83 / 109             200   no: a fixed offset from the door
    peg-insert-side  29/30           97 / 249             400   no: a fixed offset from the (visible) box
    pick-place       30/30           52.5 / 59            100   yes: a free point in the air (expert 12/30 without)
    assembly         30/30           89 / 98              150   no: the top of the (visible) peg
    stick-pull       24/30           116 / 197            300   yes: a free point on the table (expert 20/30 without)

Caps: a round number at least 1.5x the expert's longest successful episode (a learned policy is slower), never
above MetaWorld's 500. "Goal in proprio": the goal varies per seed (pick-place 6 cm std in x and z, stick-pull 3
cm in x and y), and for pick-place and stick-pull it is only a 1-3 px marker at 96 px, not something the image
shows; the other four goals sit at a fixed offset from an object the camera sees. "Expert without" is the expert
given the mean goal instead of the seed's: how much the goal matters.

Camera: corner4 for every task, flipped upright (MetaWorld's corner views come out rotated 180°). Compared with
corner, corner2, corner3, topview and behindGripper on 8 seeds x 20 frames per task (segmentation masks at 96
px): in corner4 the gripper, the object and the target are visible in every frame of every task (door-open's
goal marker in 92%), at the largest size of any fixed view (median object 10-259 px, gripper 15-22 px);
corner2 shows everything at a third of the size, corner3 at half, corner's arm hides the gripper in up to 6% of
frames, topview misses the gripper in 37-87% of frames (the arm covers it), behindGripper moves with the hand
and loses the object and target.
"""

from __future__ import annotations

from bcbench.errors import BCBenchError

IMAGE_SIZE = 96
# a larger frame for a task whose detail 96 px may lose (issue 75: "96x96, or 128 where a task needs it: measure on
# validation and say so"), named metaworld/NAME@128: its own demonstrations, its own task (run keys, stores)
LARGER_SIZES = (128,)
CAMERA = "corner4"
TIMESTEP_S = 0.0025  # MuJoCo's timestep in every MetaWorld model
FRAME_SKIP = 5  # MuJoCo steps per control step (SawyerXYZEnv's default)
CONTROL_HZ = 1.0 / (TIMESTEP_S * FRAME_SKIP)  # 80 Hz: one control step is 12.5 ms of simulated time
MAX_PATH_LENGTH = 500  # MetaWorld raises past this many steps

# proprioception: indices into MetaWorld's 39-D observation (hand xyz 0-2, gripper opening 3, goal xyz 36-38)
HAND_GRIP = (0, 1, 2, 3)
HAND_GRIP_GOAL = (0, 1, 2, 3, 36, 37, 38)
HAND_GRIP_NAMES = ("hand_x", "hand_y", "hand_z", "gripper")
GOAL_NAMES = ("goal_x", "goal_y", "goal_z")

TASKS: dict[str, dict] = {
    "drawer-open": {
        "difficulty": "easy", "env": "drawer-open-v3", "expert": "SawyerDrawerOpenV3Policy",
        "proprio": HAND_GRIP, "max_steps": 150, "camera": CAMERA,
        "expert_success": (30, 30), "expert_length": (89, 93),
    },
    "door-open": {
        "difficulty": "easy", "env": "door-open-v3", "expert": "SawyerDoorOpenV3Policy",
        "proprio": HAND_GRIP, "max_steps": 200, "camera": CAMERA,
        "expert_success": (28, 30), "expert_length": (83, 109),
    },
    "peg-insert-side": {
        "difficulty": "medium", "env": "peg-insert-side-v3", "expert": "SawyerPegInsertionSideV3Policy",
        "proprio": HAND_GRIP, "max_steps": 400, "camera": CAMERA,
        "expert_success": (29, 30), "expert_length": (97, 249),
    },
    "pick-place": {
        "difficulty": "hard", "env": "pick-place-v3", "expert": "SawyerPickPlaceV3Policy",
        "proprio": HAND_GRIP_GOAL, "max_steps": 100, "camera": CAMERA,
        "expert_success": (30, 30), "expert_length": (52.5, 59),
    },
    "assembly": {
        "difficulty": "hard", "env": "assembly-v3", "expert": "SawyerAssemblyV3Policy",
        "proprio": HAND_GRIP, "max_steps": 150, "camera": CAMERA,
        "expert_success": (30, 30), "expert_length": (89, 98),
    },
    "stick-pull": {
        "difficulty": "very hard", "env": "stick-pull-v3", "expert": "SawyerStickPullV3Policy",
        "proprio": HAND_GRIP_GOAL, "max_steps": 300, "camera": CAMERA,
        "expert_success": (24, 30), "expert_length": (116, 197),
    },
}


def split_name(name: str) -> tuple[str, int]:
    """'pick-place' -> ('pick-place', 96); 'pick-place@128' -> ('pick-place', 128). An unknown task or size is one
    BCBenchError line (the default size takes no suffix: one task, one name)."""
    base, at, size = name.partition("@")
    if base not in TASKS:
        raise BCBenchError(f"unknown MetaWorld task '{base}' (choose {', '.join(TASKS)})")
    if not at:
        return base, IMAGE_SIZE
    if size not in {str(n) for n in LARGER_SIZES}:  # "0128" would be a second name for one task
        raise BCBenchError(f"metaworld/{name}: the frame size after '@' is one of "
                         f"{', '.join(map(str, LARGER_SIZES))} (the family's {IMAGE_SIZE} px takes no suffix)")
    return base, int(size)


def state_names(name: str) -> tuple[str, ...]:
    """The proprioception's dimension names for a task (hand xyz, gripper[, goal xyz])."""
    return HAND_GRIP_NAMES + (GOAL_NAMES if TASKS[name]["proprio"] == HAND_GRIP_GOAL else ())
