"""The 3D replay viewer's frames and camera: a replay's scene at one step as arrays (``frame_at``), the team's labels,
and where a camera sits to frame the board (``framing_camera``, ``aim``). Pure data but for ``aim``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import viser

from colorgrid.config import EnvConfig
from colorgrid.replay import ReplayError, load
from colorgrid.replay.blocks import decode_blocks
from colorgrid.replay.timeline import timeline

HIDDEN_Z = -50.0  # where unused block instances wait
STEP_SECONDS = 1.0  # recording time per step: the export's slider and clock read in steps
FOV = np.deg2rad(50.0)  # vertical field of view of the opening camera
VIEW_FROM = np.array([0.0, -0.5, np.sqrt(3.0) / 2])  # look-at point to camera: from the south, 60 degrees up
WORLD_UP = np.array([0.0, 0.0, 1.0])  # viser's scene up direction (+z)
SQUARE = 1.0  # canvas aspect assumed before a tab reports its own: wider canvases see more
EXPORT_ASPECT = 4.0 / 3.0  # the export fills the window (no side panel), so it is rarely narrower


def unit_cube() -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)], dtype=np.float32)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.uint32)
    return v, f


@dataclass
class Frame:
    """The scene at one step, as arrays: what the meshes are set to (pure data, easy to test)."""

    block_positions: list  # per color: [N_k, 3] float32 (unused instances below the floor)
    agents: np.ndarray  # [A, 3] float32, in index order (the timeline's ``agent_names``)
    goal: int


def cell_xyz(cell: int, width: int, height: int, z: float) -> np.ndarray:
    """Cell index to scene coordinates: x to the right, y up the screen (row 0 at the top)."""
    r, c = divmod(int(cell), width)
    return np.array([c + 0.5, height - r - 0.5, z], dtype=np.float32)


def frame_at(data: dict, t: int, capacity: list[int]) -> Frame:
    H, W = data["height"], data["width"]
    board = data["boards"][t]
    colors = decode_blocks(board["blocks"])
    cells = np.arange(H * W)
    positions = []
    for k, cap in enumerate(capacity):
        mine = cells[colors == k]
        pos = np.zeros((cap, 3), dtype=np.float32)
        pos[:, 2] = HIDDEN_Z
        pos[: len(mine), 0] = mine % W + 0.5
        pos[: len(mine), 1] = H - mine // W - 0.5
        pos[: len(mine), 2] = 0.4
        positions.append(pos)
    agents = np.stack([cell_xyz(board[agent["name"]], W, H, 0.45) for agent in data["look"]["agents"]])
    return Frame(positions, agents, board["goal"])


def team(data: dict) -> EnvConfig:
    """The replay's config (its team: ``agent_names``, ``roles``, ``symbols``, ``one_to_one``)."""
    return EnvConfig.from_dict(data["config"])


def agent_label(agent: dict) -> str:
    """The label over an agent (an entry of the timeline's ``look["agents"]``): ``L1 (leader_0)``, ``L (leader)``."""
    return f"{agent['symbol']} ({agent['name']})"


def believer_label(data: dict, name: str) -> str:
    """How the panel names a follower with beliefs: ``follower`` in the 1:1 team, else ``F1 (follower_0)``."""
    if team(data).one_to_one:
        return name
    return next(agent_label(agent) for agent in data["look"]["agents"] if agent["name"] == name)


def block_capacity(data: dict) -> list[int]:
    """Instances per color: the most blocks of that color on any step."""
    counts = np.zeros(len(data["colors"]), dtype=np.int64)
    for board in data["boards"]:
        codes = decode_blocks(board["blocks"])
        counts = np.maximum(counts, np.bincount(codes[codes >= 0], minlength=len(counts)))
    return counts.tolist()


@dataclass(frozen=True)
class CameraPose:
    """Where a camera sits and looks, in viser's world coordinates (what ``aim`` hands to viser)."""

    position: np.ndarray  # [3]
    look_at: np.ndarray  # [3]
    up: np.ndarray  # [3] world up the camera keeps upright
    fov: float  # vertical field of view, radians


def board_bounds(data: dict) -> tuple[np.ndarray, np.ndarray]:
    """The corners ``(lo, hi)`` of the box holding the board: goal plate, floor, blocks and agents."""
    return np.array([-0.5, -0.5, -0.2]), np.array([data["width"] + 0.5, data["height"] + 0.5, 1.0])


def framing_camera(lo, hi, aspect: float = SQUARE, fov: float = FOV, margin: float = 1.08) -> CameraPose:
    """A camera looking from ``VIEW_FROM`` at the box ``lo``..``hi``, just far enough back to see all of it.

    A point is in view when, in camera coordinates, ``|right| <= depth * tan_h`` and ``|up| <= depth * tan_v``;
    the depth of a corner is the distance plus its offset along the view direction, which gives the
    closest distance for each of the eight corners in closed form. ``margin`` leaves a border around the box.
    """
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    look_at = (lo + hi) / 2
    forward = -VIEW_FROM / np.linalg.norm(VIEW_FROM)
    right = np.cross(forward, WORLD_UP)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    tan_v = np.tan(fov / 2) / margin
    tan_h = aspect * tan_v
    offset = corners - look_at  # [8, 3]
    distance = np.max(np.maximum(np.abs(offset @ right) / tan_h, np.abs(offset @ up) / tan_v) - offset @ forward)
    return CameraPose(look_at - distance * forward, look_at, WORLD_UP.copy(), float(fov))


def aim(camera, pose: CameraPose) -> None:
    """Point a tab's camera (``client.camera``) or the one new tabs and recordings open with
    (``server.initial_camera``, also the target of the client's "reset view")."""
    camera.fov = pose.fov
    if isinstance(camera, viser.CameraHandle):
        camera.up_direction = pose.up
    else:
        camera.up = pose.up
    camera.position = pose.position  # a tab's camera carries its look-at along; set the look-at after
    camera.look_at = pose.look_at


def canvas_aspect(camera) -> float:
    """The aspect to frame a tab's canvas for: its reported width over height, at most ``SQUARE``.

    Capped because the canvas narrows just after connecting, when the control panel docks beside it.
    """
    try:
        return min(camera.aspect, SQUARE) if camera.image_height > 0 else SQUARE
    except AssertionError:  # no camera message from the browser yet
        return SQUARE



def load_timeline(path: Path) -> dict:
    """A verified replay's timeline, or a ValueError that says why it cannot be shown."""
    try:
        data = timeline(load(path), path)
    except ReplayError as err:
        raise ValueError(f"{path.name}: {err.problem}") from None
    if not data["verified"]:
        raise ValueError(f"{path.name} failed verification and is not shown: {data['problem']}")
    return data


