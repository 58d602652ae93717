"""Stable-Baselines3 PPO trains a ColorGrid follower beside the A* leader, through the Gymnasium view.

The follower does not see the goal (the asymmetric setting); the A* leader does and walks to goal
blocks. SB3 trains one agent on a ``gymnasium.Env``: ``colorgrid.gym_env(seat="follower",
partners="astar", flatten=True)`` is the follower's seat, the leader played by A*, its observation one
flat float32 vector (SB3's ``MlpPolicy``; keep ``flatten=False`` for ``MultiInputPolicy``). SB3
vectorises with its own ``DummyVecEnv``/``SubprocVecEnv``, one env per copy.

    pip install 'colorgrid[examples]'
    python examples/sb3_follower.py --steps 200000 --out runs/sb3_follower

At the end it plays the trained follower and a random one beside A* on the same seeds and prints
each one's mean team reward, goal and wrong pickups per episode. A few thousand steps teach it to
avoid blocks (fewer wrong pickups than random); reading the goal from the leader takes far longer
(docs/ECOSYSTEM.md).
"""

from __future__ import annotations

import argparse

import numpy as np
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env

import colorgrid


def make_follower_env(**overrides):
    """The follower's seat beside the A* leader, observations flattened for an MLP policy."""
    return colorgrid.gym_env(seat="follower", partners="astar", flatten=True, **overrides)


def train(steps: int, seed: int = 0, envs: int = 8, **overrides) -> PPO:
    """SB3's PPO (its defaults, ``n_steps`` 128 per env) for ``steps`` env-steps."""
    vec = make_vec_env(lambda: make_follower_env(**overrides), n_envs=envs, seed=seed)
    model = PPO("MlpPolicy", vec, n_steps=128, batch_size=256, seed=seed, verbose=0)
    return model.learn(total_timesteps=steps)


def evaluate(act, episodes: int = 8, seed: int = 1000, **overrides) -> dict[str, float]:
    """Per-episode means of the team reward and the follower's goal and wrong pickups, ``act(obs) -> action``
    choosing the follower's moves; episode ``i`` is seeded ``seed + i``."""
    env = make_follower_env(**overrides)
    team, goal, wrong = [], [], []
    for i in range(episodes):
        obs, _ = env.reset(seed=seed + i)
        total, done, info = 0.0, False, {}
        while not done:
            obs, reward, terminated, truncated, info = env.step(act(obs))
            total += reward
            done = terminated or truncated
        team.append(total)
        goal.append(info["episode_goal_pickups"])
        wrong.append(info["episode_wrong_pickups"])
    return {"team_reward": float(np.mean(team)), "goal_pickups": float(np.mean(goal)),
            "wrong_pickups": float(np.mean(wrong))}


def random_act(seed: int = 0):
    """A follower that moves at random (the baseline any learning should beat)."""
    rng = np.random.default_rng(seed)
    return lambda obs: int(rng.integers(0, 4))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=16, help="evaluation episodes for each follower")
    parser.add_argument("--out", help="save the trained model here (SB3's .zip)")
    args = parser.parse_args()
    model = train(args.steps, args.seed)
    if args.out:
        model.save(args.out)
        print(f"saved {args.out}.zip")
    trained = evaluate(lambda obs: int(model.predict(obs, deterministic=True)[0]), args.episodes)
    baseline = evaluate(random_act(args.seed), args.episodes)
    for name, row in (("SB3 PPO", trained), ("random", baseline)):
        print(f"{name:8s} team reward {row['team_reward']:+6.2f}  goal pickups {row['goal_pickups']:5.2f}  "
              f"wrong pickups {row['wrong_pickups']:5.2f}  (per episode, {args.episodes} episodes beside A*)")


if __name__ == "__main__":
    main()
