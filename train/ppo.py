"""The PPO pieces as pure functions: GAE and the loss (clipped surrogate, value, entropy, auxiliary goal)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch.nn import functional as F


def compute_gae(rewards: torch.Tensor, values: torch.Tensor, next_values: torch.Tensor, dones: torch.Tensor,
                gamma: float | torch.Tensor, lam: float | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalized advantage estimation over ``[T, B]`` tensors.

    ``next_values[t]`` is the value of the state reached by step ``t`` (for a truncated
    episode, the value of its final observation, so time limits are bootstrapped; 0 for a
    true termination). ``dones[t]`` is true when step ``t`` ended an episode: the trace is cut
    there. ``gamma`` and ``lam`` are numbers, or ``[B]`` tensors: each column's own (a pack's learners side by
    side). Returns ``(advantages, returns)``.
    """
    T = rewards.shape[0]
    adv = torch.zeros_like(rewards)
    running = torch.zeros_like(rewards[0])
    for t in reversed(range(T)):
        delta = rewards[t] + gamma * next_values[t] - values[t]
        running = delta + gamma * lam * (1.0 - dones[t].float()) * running
        adv[t] = running
    return adv, adv + values


@dataclass(frozen=True)
class LossWeights:
    """The loss's coefficients (``PPOConfig.loss_weights`` makes them from a run's settings)."""

    clip_coef: float
    clip_vloss: bool
    ent_coef: float
    vf_coef: float
    aux_coef: float
    norm_adv: bool


def ppo_loss(logits: torch.Tensor, values: torch.Tensor, goal_logits: torch.Tensor, actions: torch.Tensor,
             old_logp: torch.Tensor, old_values: torch.Tensor, advantages: torch.Tensor, returns: torch.Tensor,
             goal: torch.Tensor, w: LossWeights, goal_target: torch.Tensor | None = None
             ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The PPO loss on flat samples: ``logits [N, A]``, ``values [N]``, ``goal_logits [N, C]``, the rest ``[N]``.

    total = policy loss - ent_coef * entropy + vf_coef * value loss + aux_coef * goal cross-entropy, the
    cross-entropy against ``goal_target [N, C]`` (a teacher's belief) when given, else against the true ``goal``
    (which ``goal_accuracy`` always scores).
    """
    logp_all = torch.log_softmax(logits, dim=-1)
    logp = logp_all.gather(1, actions[:, None])[:, 0]
    entropy = -(logp_all.exp() * logp_all).sum(dim=-1).mean()
    log_ratio = logp - old_logp
    ratio = log_ratio.exp()
    adv = advantages
    if w.norm_adv and adv.numel() > 1:
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    pg_loss = torch.max(-adv * ratio, -adv * ratio.clamp(1 - w.clip_coef, 1 + w.clip_coef)).mean()
    if w.clip_vloss:
        clipped = old_values + (values - old_values).clamp(-w.clip_coef, w.clip_coef)
        v_loss = 0.5 * torch.max((values - returns) ** 2, (clipped - returns) ** 2).mean()
    else:
        v_loss = 0.5 * ((values - returns) ** 2).mean()
    aux_loss = F.cross_entropy(goal_logits, goal if goal_target is None else goal_target)
    total = pg_loss - w.ent_coef * entropy + w.vf_coef * v_loss + w.aux_coef * aux_loss
    with torch.no_grad():
        stats = {
            "loss": total, "policy_loss": pg_loss, "value_loss": v_loss, "entropy": entropy, "aux_loss": aux_loss,
            "approx_kl": ((ratio - 1) - log_ratio).mean(),
            "clip_frac": ((ratio - 1.0).abs() > w.clip_coef).float().mean(),
            "goal_accuracy": (goal_logits.argmax(dim=-1) == goal).float().mean(),
        }
    return total, {k: v.detach() for k, v in stats.items()}


def explained_variance(values: torch.Tensor, returns: torch.Tensor) -> float:
    var = returns.var()
    return float("nan") if var == 0 else float(1 - (returns - values).var() / var)
