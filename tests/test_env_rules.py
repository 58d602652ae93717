"""One test per rule of the environment (docs/ENV_CARD.md)."""

import numpy as np
import pytest

from colorgrid import BatchEnv, EnvConfig
from tests.helpers import DOWN, LEFT, RIGHT, STAY, UP, check_consistent, env_from_text, step1

# 4x4 grid with exactly one block of each color.
SMALL = EnvConfig(height=4, width=4, block_density=0.2, switch_prob=0.0)


def cells(env):
    return [divmod(int(c), env.config.width) for c in env.state.agent_cell[0]]


def test_moves_follow_the_action_table():
    env = env_from_text(SMALL, """
        ....
        .L..
        ...F
        rgb.
    """)
    for action, expected in [(UP, (0, 1)), (RIGHT, (0, 2)), (DOWN, (1, 2)), (LEFT, (1, 1))]:
        step1(env, action, LEFT if action == RIGHT else RIGHT)  # follower bounces on the right wall
        assert cells(env)[0] == expected


def test_walls_leave_an_agent_in_place():
    env = env_from_text(SMALL, """
        L...
        ....
        ....
        rgbF
    """)
    step1(env, UP, DOWN)
    assert cells(env) == [(0, 0), (3, 3)]
    step1(env, LEFT, RIGHT)
    assert cells(env) == [(0, 0), (3, 3)]


def test_no_overlap_and_no_swap():
    env = env_from_text(SMALL, """
        LF..
        ....
        ....
        rgb.
    """)
    step1(env, RIGHT, LEFT)  # head-on: leader blocked by the follower's cell, follower by the leader's
    assert cells(env) == [(0, 0), (0, 1)]
    step1(env, DOWN, LEFT)  # leader leaves first, so the follower may take its old cell
    assert cells(env) == [(1, 0), (0, 0)]
    step1(env, UP, RIGHT)  # leader's target is the follower's current cell: blocked
    assert cells(env) == [(1, 0), (0, 1)]
    step1(env, STAY if SMALL.allow_stay else RIGHT, DOWN)  # follower moves into the leader's new cell
    assert cells(env) == [(1, 1), (0, 1)]


def test_agents_never_overlap_under_random_play():
    env = BatchEnv(EnvConfig(height=6, width=6, block_density=0.2), num_envs=64, seed=3)
    env.reset()
    rng = np.random.default_rng(0)
    for _ in range(400):
        env.step(rng.integers(0, 4, (64, 2)))
        check_consistent(env)


@pytest.mark.parametrize("mode", ["shared", "individual"])
def test_pickup_rewards(mode):
    cfg = SMALL.replace(reward_mode=mode, goal_reward=4.0, wrong_penalty=1.0)
    env = env_from_text(cfg, """
        .L..
        ....
        r.F.
        ..gb
    """, goal="red")
    _, rewards, _, _, info = step1(env, DOWN, DOWN)  # leader to (1,1): nothing; follower onto green
    assert info["block_reward"][0].tolist() == [0.0, -1.0]
    expected = [-1.0, -1.0] if mode == "shared" else [0.0, -1.0]
    assert rewards[0].tolist() == expected
    assert info["team_reward"][0] == -1.0
    assert info["wrong_pickup"][0].tolist() == [False, True]
    assert info["picked_color"][0].tolist() == [-1, 1]
    step1(env, LEFT, LEFT)  # leader (1,0); follower (3,1)
    _, rewards, _, _, info = step1(env, DOWN, STAY if cfg.allow_stay else LEFT)  # leader onto red, the goal
    assert info["goal_pickup"][0].tolist() == [True, False]
    assert info["block_reward"][0, 0] == 4.0
    assert env.state.goal_pickups[0].tolist() == [1, 0]
    assert env.state.wrong_pickups[0].tolist() == [0, 1]


def test_penalty_coefficient_scales_wrong_pickups_and_is_settable():
    env = env_from_text(SMALL.replace(wrong_penalty=2.0), """
        .L..
        .g..
        ..F.
        r..b
    """, goal="red")
    env.penalty_coef = 0.25
    _, rewards, _, _, info = step1(env, DOWN, UP)
    assert info["block_reward"][0, 0] == -0.5 and info["penalty_coef"] == 0.25
    with pytest.raises(ValueError, match="penalty_coef must be a finite number >= 0"):
        env.penalty_coef = -1


def test_collected_block_respawns_on_a_free_cell_with_the_same_color():
    cfg = EnvConfig(height=4, width=4, block_density=0.75, switch_prob=0.0)  # 4 per color: 12 blocks
    env = env_from_text(cfg, """
        rrrr
        gggg
        bbbb
        L..F
    """)
    step1(env, UP, UP)  # both collect; leader's block then follower's must land on the free cells
    check_consistent(env)
    # After the moves the agents stand on (2,0) and (2,3); the only cells with no block and no agent
    # are the bottom row's four, so both blue blocks must land there, on distinct cells.
    landed = {divmod(int(c), 4) for c in env.state.block_cell[0, [8, 11]]}
    assert len(landed) == 2 and landed <= {(3, 0), (3, 1), (3, 2), (3, 3)}
    assert (env.state.block_colors(cfg)[0] == 2).sum() == 4


def test_block_counts_constant_and_respawns_avoid_occupied_cells():
    env = BatchEnv(EnvConfig(height=8, width=8, block_density=0.5), num_envs=32, seed=11)
    env.reset()
    rng = np.random.default_rng(1)
    pickups = 0
    for _ in range(300):
        _, _, _, _, info = env.step(rng.integers(0, 4, (32, 2)))
        pickups += int((info["picked_color"] >= 0).sum())
        check_consistent(env)
        counts = np.stack([(env.state.block_colors(env.config) == k).sum(axis=(1, 2)) for k in range(3)])
        assert (counts == env.config.blocks_per_color).all()
    assert pickups > 500


def test_respawn_is_uniform_over_free_cells():
    # Many independent pickups of the same block from the same layout: every free cell gets hit.
    cfg = EnvConfig(height=4, width=4, block_density=0.2, switch_prob=0.0)
    text = """
        .L..
        .r..
        ...F
        .g.b
    """
    from colorgrid.scenario import state_from_text

    landed = []
    for seed in range(1200):
        env = BatchEnv(cfg, 1, seed=seed)
        env.load_state(state_from_text(cfg, text, seed=seed))
        step1(env, DOWN, UP)
        landed.append(int(env.state.block_cell[0, 0]))
    counts = np.bincount(landed, minlength=16)
    occupied = [1 * 4 + 1, 1 * 4 + 3, 3 * 4 + 1, 3 * 4 + 3]  # leader, follower, green, blue after the step
    assert counts[occupied].sum() == 0
    free = np.setdiff1d(np.arange(16), occupied)
    assert (counts[free] > 1200 / 12 * 0.6).all() and (counts[free] < 1200 / 12 * 1.4).all()


def test_goal_switches_to_another_color_at_the_stated_rate():
    p, n_env, steps = 0.1, 256, 400
    env = BatchEnv(EnvConfig(switch_prob=p, num_colors=4, height=8, width=8, block_density=0.2, horizon=10_000),
                   num_envs=n_env, seed=5)
    env.reset()
    rng = np.random.default_rng(2)
    switches, prev = 0, env.state.goal.copy()
    new_colors = np.zeros((4, 4), dtype=int)
    for _ in range(steps):
        _, _, _, _, info = env.step(rng.integers(0, 4, (n_env, 2)))
        goal = info["goal_color"]
        changed = goal != prev
        assert (changed == info["goal_switched"]).all(), "a switch always changes the color"
        np.add.at(new_colors, (prev[changed], goal[changed]), 1)
        switches += int(changed.sum())
        prev = goal.copy()
    trials = n_env * steps
    sigma = np.sqrt(trials * p * (1 - p))
    # Seeds are fixed, so this cannot flake; the 6-sigma band is what a correct rate must meet.
    assert abs(switches - trials * p) < 6 * sigma
    assert np.trace(new_colors) == 0
    off = new_colors[~np.eye(4, dtype=bool)]
    assert off.min() > 0.75 * off.mean() and off.max() < 1.25 * off.mean()


def test_stationary_goal_never_switches():
    env = BatchEnv(EnvConfig(switch_prob=0.0), num_envs=16, seed=0)
    env.reset()
    goal = env.state.goal.copy()
    for _ in range(127):
        env.step(np.zeros((16, 2), dtype=int))
    assert (env.state.goal == goal).all()


def test_truncation_at_the_horizon_and_same_step_autoreset():
    env = BatchEnv(EnvConfig(horizon=5), num_envs=3, seed=0)
    env.reset()
    first_seeds = env.state.seed.copy()
    for t in range(1, 6):
        obs, _, terms, truncs, info = env.step(np.zeros((3, 2), dtype=int))
        assert not terms.any()
        assert truncs.all() == (t == 5) and truncs.any() == (t == 5)
    assert info["_final_obs"].all()
    assert info["final_info"]["episode_length"].tolist() == [5, 5, 5]
    assert (info["final_info"]["seed"] == first_seeds).all()
    assert (env.state.t == 0).all() and (env.state.seed != first_seeds).all()
    assert not np.array_equal(info["final_obs"]["observation"], obs["observation"])


def test_without_autoreset_stepping_an_ended_episode_raises():
    env = BatchEnv(EnvConfig(horizon=2), num_envs=1, seed=0, autoreset=False)
    env.reset()
    env.step(np.zeros((1, 2), dtype=int))
    env.step(np.zeros((1, 2), dtype=int))
    with pytest.raises(RuntimeError, match="call reset"):
        env.step(np.zeros((1, 2), dtype=int))


def test_hemispheres_confine_agents_and_respawn_in_the_same_half():
    cfg = EnvConfig(hemispheres=True, height=8, width=8, block_density=0.25)
    env = BatchEnv(cfg, num_envs=32, seed=2)
    env.reset()
    half = lambda cells: (cells % 8) >= 4  # noqa: E731
    start_half = half(env.state.block_cell)
    for k in range(cfg.num_colors):  # each color spread evenly over the halves
        per_color = start_half[:, k * cfg.blocks_per_color:(k + 1) * cfg.blocks_per_color].sum(axis=1)
        assert (np.abs(per_color * 2 - cfg.blocks_per_color) <= 1).all()
    rng = np.random.default_rng(3)
    for _ in range(300):
        env.step(rng.integers(0, 4, (32, 2)))
        assert (env.state.agent_cell[:, 0] % 8 < 4).all() and (env.state.agent_cell[:, 1] % 8 >= 4).all()
        assert (half(env.state.block_cell) == start_half).all()
        check_consistent(env)


def test_asymmetric_hides_the_goal_from_the_follower_only():
    for asymmetric in (True, False):
        env = BatchEnv(EnvConfig(asymmetric=asymmetric, switch_prob=0.5), num_envs=8, seed=0)
        obs, _ = env.reset()
        for _ in range(20):
            gi = obs["goal_info"]
            assert (gi[:, 0].argmax(axis=1) == env.state.goal).all() and (gi[:, 0].sum(axis=1) == 1).all()
            assert (gi[:, 1] == (0 if asymmetric else gi[:, 0])).all()
            obs, *_ = env.step(np.zeros((8, 2), dtype=int))


def test_distance_penalty_applies_to_chosen_agents_within_the_threshold():
    cfg = SMALL.replace(distance_penalty=0.25, distance_threshold=2, distance_penalty_agents=("leader",))
    env = env_from_text(cfg, """
        L...
        ....
        ....
        rgbF
    """)
    _, rewards, _, _, info = step1(env, RIGHT, UP)  # distance 4 after the move
    assert info["distance_shaping"][0].tolist() == [0.0, 0.0]
    _, rewards, _, _, info = step1(env, DOWN, UP)  # leader (1,1), follower (1,3): distance 2
    assert info["distance_shaping"][0].tolist() == [-0.25, 0.0]
    assert rewards[0].tolist() == [-0.25, 0.0]


def test_potential_field_matches_a_hand_computed_value():
    cfg = SMALL.replace(potential_shaping=True, potential_scale=0.2, wrong_penalty=2.0)
    env = env_from_text(cfg, """
        L...
        ....
        ....
        rgbF
    """, goal="green")
    _, rewards, _, _, info = step1(env, DOWN, LEFT)  # leader (1,0), follower (3,3) blocked? no: (3,2) has blue
    # After the move: leader (1,0); follower collected blue at (3,2), which respawned somewhere.
    leader = np.array([1, 0])
    blocks = env.state.block_pos[0]
    d = np.abs(blocks - leader).sum(axis=1)
    expected = 0.2 * (1 / (d[1] + 1) - 2.0 * (1 / (d[0] + 1) + 1 / (d[2] + 1)))
    assert info["potential_shaping"][0, 0] == pytest.approx(expected)
    assert info["block_reward"][0, 0] == 0.0 and rewards[0, 0] == pytest.approx(expected - 2.0, rel=1e-5)


def test_invalid_actions_get_clear_errors():
    env = BatchEnv(EnvConfig(), num_envs=2, seed=0)
    env.reset()
    with pytest.raises(ValueError, match=r"actions must have shape \(2, 2\)"):
        env.step(np.zeros((2,), dtype=int))
    with pytest.raises(ValueError, match=r"actions must be in \[0, 4\) \(up, down, left, right\).*allow_stay"):
        env.step(np.full((2, 2), 4))
    with pytest.raises(ValueError, match="actions must be integers"):
        env.step(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="num_envs must be a positive integer"):
        BatchEnv(EnvConfig(), num_envs=0)


def test_compiled_step_draws_the_same_random_numbers_as_the_vectorised_hash():
    from colorgrid import rng
    from colorgrid.kernel import hash64

    gen = np.random.default_rng(3)
    seeds = gen.integers(0, 2**63 - 1, 200, dtype=np.uint64)
    steps = gen.integers(0, 10_000, 200)
    for stream in (rng.STREAM_RESPAWN, rng.STREAM_SWITCH, rng.STREAM_SWITCH_COLOR):
        for attempt, index in ((0, 0), (3, 1), (999_999, 0)):
            expected = rng.hash64(seeds, steps, stream, attempt, index)
            got = [hash64(np.uint64(s), int(t), np.uint64(stream), attempt, index) for s, t in zip(seeds, steps)]
            assert np.array_equal(np.array(got, dtype=np.uint64), expected)
