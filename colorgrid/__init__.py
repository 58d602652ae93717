"""ColorGrid: a multi-agent gridworld for inferring a partner's hidden, changing goal."""

from colorgrid.config import AGENTS, COLOR_NAMES, ENV_ID, EnvConfig
from colorgrid.env import ACTION_NAMES, BatchEnv
from colorgrid.gym_env import GYM_ID, SeatEnv, SeatVectorEnv, gym_env, gym_vector_env, register
from colorgrid.pettingzoo_env import ColorGridParallelEnv, env, parallel_env
from colorgrid.render import render_ansi, render_rgb
from colorgrid.state import EnvState

__all__ = [
    "AGENTS", "ACTION_NAMES", "COLOR_NAMES", "ENV_ID", "GYM_ID", "BatchEnv", "ColorGridParallelEnv", "EnvConfig",
    "EnvState", "SeatEnv", "SeatVectorEnv", "env", "gym_env", "gym_vector_env", "parallel_env", "render_ansi",
    "render_rgb",
]
register()  # gymnasium.make(GYM_ID, seat="follower", partners="astar")
__version__ = "0.1.0"
