"""Teams of any shape (``num_leaders`` x ``num_followers``): the generalised rules on hand-built boards,
random play, batch equals single, the PettingZoo views and the 1:1 team kept as it was."""

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test, render_test

from colorgrid import AGENTS, ENV_ID, BatchEnv, EnvConfig, env, parallel_env, render_ansi, render_rgb
from colorgrid.config import TEAM_ENV_ID
from colorgrid.render import AGENT_COLORS
from tests.helpers import DOWN, LEFT, RIGHT, UP, check_consistent, env_from_text, step1

SHAPES = [(2, 1), (1, 2), (2, 2), (3, 3)]
# 5x5, one block of each color, no switches: room for hand-built teams.
SMALL = dict(height=5, width=5, block_density=0.12, switch_prob=0.0)


def team(leaders, followers, **changes) -> EnvConfig:
    return EnvConfig(num_leaders=leaders, num_followers=followers, **{**SMALL, **changes})


def cells(e):
    return [divmod(int(c), e.config.width) for c in e.state.agent_cell[0]]


def test_names_roles_symbols_and_env_ids():
    one = EnvConfig()
    assert one.agent_names == AGENTS == ("leader", "follower") and one.symbols == ("L", "F")
    assert one.env_id == ENV_ID and one.num_planes == 5
    cfg = EnvConfig(num_leaders=2, num_followers=3)
    assert cfg.agent_names == ("leader_0", "leader_1", "follower_0", "follower_1", "follower_2")
    assert cfg.roles == ("leader", "leader", "follower", "follower", "follower")
    assert cfg.symbols == ("L1", "L2", "F1", "F2", "F3")
    assert list(cfg.leaders) == [0, 1] and list(cfg.followers) == [2, 3, 4]
    assert cfg.env_id == TEAM_ENV_ID != ENV_ID and cfg.num_planes == 3 + 5
    assert cfg.index("follower_1") == 3
    with pytest.raises(ValueError, match="its agents are"):
        cfg.index("follower")


@pytest.mark.parametrize("changes, message", [
    (dict(num_leaders=0), r"num_leaders must be an integer in \[1, 8\], got 0"),
    (dict(num_followers=9), r"num_followers must be an integer in \[1, 8\], got 9"),
    (dict(num_leaders=True), r"num_leaders must be an integer"),
    (dict(num_leaders=2, distance_penalty_agents=("follower_1",)), r"distance_penalty_agents must be .*leader_1"),
])
def test_bad_team_settings_get_one_line_errors(changes, message):
    with pytest.raises(ValueError, match=message) as err:
        EnvConfig(**changes)
    assert "\n" not in str(err.value)


def test_the_lowest_index_claims_a_contested_cell():
    e = env_from_text(team(2, 1), """
        L1.L2..
        .F1...
        .....
        .....
        rgb..
    """, goal=0)
    # L1 (0,0) and L2 (0,2) both step into (0,1); F1 (1,1) steps up into it too
    step1(e, RIGHT, LEFT, UP)
    assert cells(e) == [(0, 1), (0, 2), (1, 1)]
    check_consistent(e)


def test_no_pair_swaps_and_moves_resolve_in_agent_order():
    e = env_from_text(team(2, 2), """
        L1L2...
        F1F2...
        .....
        .....
        rgb..
    """)
    step1(e, RIGHT, LEFT, RIGHT, LEFT)  # every pair head-on: nobody moves
    assert cells(e) == [(0, 0), (0, 1), (1, 0), (1, 1)]
    step1(e, DOWN, DOWN, RIGHT, RIGHT)  # L1 into F1's current cell: blocked; L2 too; F1 into F2's: blocked; F2 moves
    assert cells(e) == [(0, 0), (0, 1), (1, 0), (1, 2)]
    step1(e, RIGHT, RIGHT, RIGHT, UP)  # L1 into L2's current cell: blocked (L2 moves later); L2 moves; F2 blocked
    assert cells(e) == [(0, 0), (0, 2), (1, 1), (1, 2)]
    step1(e, DOWN, LEFT, UP, DOWN)  # F1 moves up into (0,1), L2 moved left before it: L2 takes it, F1 stays
    assert cells(e) == [(1, 0), (0, 1), (1, 1), (2, 2)]
    check_consistent(e)


@pytest.mark.parametrize("leaders, followers", SHAPES)
@pytest.mark.parametrize("hemispheres", [False, True])
def test_random_play_keeps_every_rule(leaders, followers, hemispheres):
    cfg = EnvConfig(num_leaders=leaders, num_followers=followers, height=8, width=8, block_density=0.2,
                    hemispheres=hemispheres, allow_stay=True)
    e = BatchEnv(cfg, num_envs=32, seed=5)
    e.reset()
    rng = np.random.default_rng(0)
    A, half = cfg.num_agents, cfg.width // 2
    collected = 0
    for _ in range(300):
        before = e.state.agent_cell.copy()
        actions = rng.integers(0, cfg.num_actions, (32, A))
        _, rewards, _, _, info = e.step(actions)
        ended = info.get("_final_obs", np.zeros(32, dtype=bool))
        after = e.state.agent_cell
        live = ~ended
        for a in range(A):
            for o in range(a + 1, A):
                swapped = (after[:, a] == before[:, o]) & (after[:, o] == before[:, a])
                assert not swapped[live].any(), f"agents {a} and {o} swapped"
        if hemispheres:
            cols = after % cfg.width
            assert (cols[:, list(cfg.leaders)] < half).all() and (cols[:, list(cfg.followers)] >= half).all()
        collected += int((info["picked_color"] >= 0).sum())
        # shared reward: every agent's reward is the team's block reward this step
        assert np.allclose(rewards, info["block_reward"].sum(axis=1, keepdims=True))
        check_consistent(e)  # no overlap, no block under an agent, planes agree with the state
    assert collected > 50


def test_goal_info_for_every_leader_and_no_follower_in_the_asymmetric_setting():
    for asymmetric in (True, False):
        cfg = EnvConfig(num_leaders=2, num_followers=3, asymmetric=asymmetric)
        obs, _ = BatchEnv(cfg, num_envs=4, seed=1).reset()
        shown = obs["goal_info"].sum(axis=2)  # [B, A]
        assert (shown[:, :2] == 1).all()
        assert (shown[:, 2:] == (0 if asymmetric else 1)).all()


def test_distance_penalty_applies_near_an_agent_of_the_other_role():
    cfg = team(1, 2, distance_penalty=0.5, distance_threshold=2)
    e = env_from_text(cfg, """
        F1F2...
        .....
        .....
        .....
        rgb.L1
    """)
    *_, info = step1(e, RIGHT, LEFT, RIGHT)  # L1 and F1 stay at walls, F2 to (0,2): followers 2 apart only
    assert cells(e) == [(4, 4), (0, 0), (0, 2)]
    assert info["distance_shaping"][0].tolist() == [0.0, 0.0, 0.0], "two followers near each other: no penalty"
    e = env_from_text(cfg.replace(distance_threshold=1), """
        L1F1...
        .....
        ....F2
        .....
        rgb..
    """)
    step1(e, LEFT, RIGHT, LEFT)  # L1 (0,0), F1 (0,2), F2 (2,3)
    step1(e, DOWN, LEFT, LEFT)  # L1 (1,0), F1 (0,1), F2 (2,2)
    *_, info = step1(e, RIGHT, LEFT, UP)  # L1 (1,1), F1 (0,0) two away, F2 (1,2) next to L1
    assert cells(e) == [(1, 1), (0, 0), (1, 2)]
    assert info["distance_shaping"][0].tolist() == [0.0, 0.0, -0.5], "followers only, by default"
    e2 = BatchEnv(cfg.replace(distance_penalty_agents=("leader", "follower_1")), num_envs=1)
    e2.load_state(e.state)
    *_, info = step1(e2, UP, RIGHT, LEFT)  # L1 (0,1); F1 blocked by L1's new cell; F2 into L1's old cell
    assert cells(e2) == [(0, 1), (0, 0), (1, 1)]
    assert info["distance_shaping"][0].tolist() == [-0.5, 0.0, -0.5], "a role and an agent, by name"


@pytest.mark.parametrize("leaders, followers", SHAPES)
def test_env_i_of_a_batch_equals_a_single_env(leaders, followers):
    cfg = EnvConfig(num_leaders=leaders, num_followers=followers)
    rng = np.random.default_rng(2)
    actions = rng.integers(0, 4, (260, 3, cfg.num_agents))
    batch = BatchEnv(cfg, num_envs=3, seed=40)
    batch.reset()
    singles = [BatchEnv(cfg, num_envs=1, seed=40 + i) for i in range(3)]
    for s in singles:
        s.reset()
    for a in actions:
        batch.step(a)
        for i, s in enumerate(singles):
            s.step(a[i:i + 1])
            assert s.state.state_hash(0) == batch.state.state_hash(i)


def test_same_seed_same_trajectory_different_seed_differs():
    cfg = EnvConfig(num_leaders=3, num_followers=2)

    def run(seed):
        e = BatchEnv(cfg, num_envs=2, seed=seed)
        e.reset()
        for a in np.random.default_rng(0).integers(0, 4, (300, 2, 5)):
            e.step(a)
        return [e.state.state_hash(i) for i in range(2)]

    assert run(7) == run(7) and run(7) != run(8)


@pytest.mark.parametrize("leaders, followers", SHAPES)
def test_pettingzoo_views_of_every_team_shape(leaders, followers):
    e = parallel_env(num_leaders=leaders, num_followers=followers)
    names = [f"leader_{i}" for i in range(leaders)] + [f"follower_{i}" for i in range(followers)]
    assert e.possible_agents == names and e.metadata["name"] == TEAM_ENV_ID
    parallel_api_test(e, num_cycles=150)
    parallel_seed_test(lambda: parallel_env(num_leaders=leaders, num_followers=followers))
    obs, _ = e.reset(seed=3)
    C, A = e.config.num_colors, e.config.num_agents
    for i, name in enumerate(names):
        planes = obs[name]["observation"]
        assert planes.shape == (C + A + 1, 32, 32)
        assert (planes[-1] == planes[C + i]).all() and planes[-1].sum() == 1, "the last plane marks the observer"
        assert obs[name]["goal_info"].sum() == (1 if name.startswith("leader") else 0)
    render_test(lambda render_mode=None: env(num_leaders=leaders, num_followers=followers, render_mode=render_mode))


def test_the_one_to_one_view_keeps_its_names_and_planes():
    e = parallel_env()
    obs, _ = e.reset(seed=0)
    assert e.possible_agents == ["leader", "follower"] and e.metadata["name"] == ENV_ID
    assert obs["leader"]["observation"].shape == (5, 32, 32)


def test_pictures_label_every_agent_in_its_role_colors():
    cfg = EnvConfig(num_leaders=2, num_followers=2)
    e = BatchEnv(cfg, num_envs=1, seed=3)
    e.reset()
    text = render_ansi(e.state, cfg, color=False)
    grid = "".join(text.splitlines()[1:])
    for label in ("L1", "L2", "F1", "F2"):
        assert grid.count(label) == 1
    assert text.splitlines()[0].endswith("leader_0 +0 leader_1 +0 follower_0 +0 follower_1 +0")
    frame = render_rgb(e.state, cfg, cell=16)
    drawn = []
    for a, role in enumerate(cfg.roles):
        row, col = divmod(int(e.state.agent_cell[0, a]), 32)
        tile = frame[22 + 4 + row * 16: 22 + 4 + row * 16 + 16, 4 + col * 16: 4 + col * 16 + 16]
        assert (tile == AGENT_COLORS[role][0]).all(axis=-1).sum() > 30, "the body is its role's color"
        drawn.append(tile.astype(int))
    for a in range(4):
        for o in range(a + 1, 4):
            assert np.abs(drawn[a] - drawn[o]).sum() > 0, f"agents {a} and {o} look the same: labels missing"


def test_hemispheres_need_room_for_the_larger_role():
    EnvConfig(num_leaders=4, num_followers=1, height=4, width=4, block_density=0.2, hemispheres=True)
    with pytest.raises(ValueError, match="keeps a free cell"):
        EnvConfig(num_leaders=8, num_followers=1, height=4, width=4, block_density=0.2, hemispheres=True)


def test_demo_prints_every_agents_score_of_the_episode_it_played():
    import ast
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "colorgrid_apps", "demo", "--quiet", "--seed", "2", "--set",
                          "num_leaders=2"], capture_output=True, text=True, check=True).stdout
    printed = ast.literal_eval(out.strip().removeprefix("episode over: "))
    cfg = EnvConfig(num_leaders=2)
    e = BatchEnv(cfg, num_envs=1, seed=2, autoreset=False)
    e.reset()
    rng = np.random.default_rng(2)
    for _ in range(cfg.horizon):
        e.step(rng.integers(0, cfg.num_actions, (1, cfg.num_agents)))
    assert printed == dict(zip(cfg.agent_names, e.state.score[0].tolist()))
    assert any(printed.values()), "the scores of the finished episode, not of the next one"


def test_a_one_to_one_config_writes_no_team_fields_and_a_team_config_round_trips():
    assert "num_leaders" not in EnvConfig().to_dict() and "num_followers" not in EnvConfig().to_dict()
    team_config = EnvConfig(num_leaders=2, num_followers=3)
    assert team_config.to_dict()["num_leaders"] == 2
    assert EnvConfig.from_dict(team_config.to_dict()) == team_config
    assert EnvConfig.from_dict(EnvConfig().to_dict()) == EnvConfig()
