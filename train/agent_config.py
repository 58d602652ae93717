"""One role's training settings (``TrainConfig.leader`` and ``.follower``): its actor-critic (``NetConfig``) and how
each of its agents plays and learns (``AgentConfig``: learn, a frozen checkpoint or a scripted policy, its
auxiliary goal loss, its reward). ``train.config`` holds the run around them and re-exports both."""

from __future__ import annotations

from dataclasses import dataclass, field

from colorgrid.configkit import check_bool, check_choice, check_int, check_number, check_strings, fail
from colorgrid.policies.names import policy_names, read_name

ARCHS = ("fast", "paper")
GOAL_FUSIONS = ("flat", "projected", "heads", "planes")
GOAL_FUSION_ALIASES = {"early": "flat", "late": "heads"}
"""Earlier names of two fusions, still read (checkpoints and presets saved with them load unchanged). The old
``late`` is ``heads``, not the paper's "late", which is ``projected``."""


def between(low: float, high: float, low_open: bool = False, high_open: bool = False):
    """A check that a number lies in ``[low, high]`` (each end open when asked)."""
    return lambda v: (low < v if low_open else low <= v) and (v < high if high_open else v <= high)


@dataclass(frozen=True)
class NetConfig:
    """The actor-critic of one agent."""

    arch: str = "fast"
    """``fast``: egocentric view, downsampled in the first conv (CPU-friendly). ``paper``: the paper's exact net."""
    lstm: bool = False
    """Add an LSTM core (trained with truncated BPTT over whole rollouts)."""
    lstm_size: int = 128
    hidden: int = 128
    """Width of the fast net's trunk (the paper net is fixed at 192)."""
    goal_fusion: str = "flat"
    """Where the goal one-hot joins: ``flat`` (with the flattened conv features, at the trunk's first layer: the
    paper's text and its "early"), ``projected`` (``paper`` only: after the 43264->192 projection, as the paper's
    code builds it and its "late"), ``heads`` (with the trunk's output, before the heads) or ``planes`` (the block
    planes are split into goal-colored blocks and the rest, as two extra input planes; with ``belief_input`` the
    split uses the agent's own belief, from an LSTM over the last-step inputs). The other side inputs
    (``extra_inputs``, a shared network's identity) join where ``flat`` or ``projected`` joins the goal. Earlier
    names: ``early`` is ``flat``, ``late`` is ``heads``."""
    extra_inputs: bool = False
    """Also feed last step's team reward, both agents' actions and the colors they collected."""
    belief_input: bool = False
    """Feed the agent's own goal prediction (detached softmax of the auxiliary head) to its policy and value heads."""
    leader_progress: bool = False
    """The belief core also reads, for each leader and color, whether the leader's last move took it nearer
    to (+1) or farther from (-1) the nearest block of that color (``train.inputs.leader_progress``): the
    evidence a Bayesian follower reads from the board, which the core's other inputs do not show."""

    def __post_init__(self):
        check_choice(self, "arch", ARCHS, f"choose one of {list(ARCHS)}")
        if self.goal_fusion in GOAL_FUSION_ALIASES:  # a name from before the paper code's fusion was added
            object.__setattr__(self, "goal_fusion", GOAL_FUSION_ALIASES[self.goal_fusion])
        check_choice(self, "goal_fusion", GOAL_FUSIONS, f"choose one of {list(GOAL_FUSIONS)}")
        if self.goal_fusion == "projected" and self.arch != "paper":
            fail(self, "goal_fusion", "'projected' joins the goal after the paper network's 43264->192 projection: "
                 "set net.arch='paper' too, or choose 'flat', 'heads' or 'planes'")
        for name in ("lstm_size", "hidden"):
            check_int(self, name, 1, 4096)
        for name in ("lstm", "extra_inputs", "belief_input", "leader_progress"):
            check_bool(self, name)
        if self.leader_progress and not (self.goal_fusion == "planes" and self.belief_input):
            fail(self, "leader_progress", "it is an input of the belief core: set net.goal_fusion='planes', "
                 "net.belief_input=true, net.lstm=true and net.extra_inputs=true too")
        if self.goal_fusion == "planes" and self.belief_input and not (self.lstm and self.extra_inputs):
            fail(self, "belief_input", "with goal_fusion='planes' the belief comes from an LSTM over the last-step "
                 "inputs: set net.lstm=true and net.extra_inputs=true too")


@dataclass(frozen=True)
class AgentConfig:
    """How the agents of one role take part in a run: ``TrainConfig.leader`` holds every leader's settings,
    ``TrainConfig.follower`` every follower's (in the 1:1 team, the one leader's and the one follower's)."""

    policy: str = "learn"
    """``learn`` (trained here), a scripted policy name (``astar``, ``idle``, ``bayes``, ...), or a checkpoint path
    (frozen), for every agent of the role (``policies`` sets one per agent)."""
    policies: tuple[str, ...] = ()
    """One policy per agent of the role, in index order, each as ``policy`` takes it; empty: every agent plays
    ``policy``. E.g. ``leader.policies=["astar", "learn"]``: the first leader is scripted, the second learns."""
    share_network: bool = False
    """With two or more learning agents in the role: one network and optimizer for all of them (parameter
    sharing), which gets each agent's position among them as a one-hot input; false: one network each."""
    init: str | None = None
    """For ``learn``: warm-start weights (and network settings) from this checkpoint (every learner of the role)."""
    net: NetConfig = field(default_factory=NetConfig)
    aux_coef: float = 0.2
    """Weight kappa of the auxiliary goal-prediction cross-entropy (0 turns it off)."""
    aux_target: str = "goal"
    """What the auxiliary head learns to predict: ``goal`` (the true current goal) or a policy name whose
    belief over the goal it is distilled from (``bayes``, ``bayes-people``, with parameters as
    name:key=value,...): that policy watches every env beside the learner, from the learner's own inputs,
    and its belief is the head's soft target. Acting never reads it."""
    lr: float | None = None
    """Learning rate for this agent; None uses ``ppo.lr``."""
    train_reward: str = "env"
    """What this agent learns from: ``env`` (the env's reward for it: the team reward in ``shared`` mode) or
    ``own`` (its own block reward, plus shaping). ``own`` gives a cleaner credit signal while the env, and so
    the agent's inputs and all metrics, stay in the configured reward mode."""
    wrong_weight: float = 1.0
    """With ``train_reward='own'``: each wrong block this agent collects costs it ``wrong_weight`` times the
    env's penalty in its learning signal (a caution weight: above 1 it collects a block only when surer of
    the goal). The env's rewards, the agent's inputs and every metric are unchanged."""

    @property
    def learns(self) -> bool:
        return self.policy == "learn"

    def agent_policies(self, count: int) -> tuple[str, ...]:
        """The policy of each of the role's ``count`` agents (``policies``, or ``policy`` for every one)."""
        return self.policies or (self.policy,) * count

    def __post_init__(self):
        if not isinstance(self.policy, str) or not self.policy:
            fail(self, "policy", "'learn', a scripted policy name or a checkpoint path ending in .pt")
        names = policy_names()
        allowed = (f"'learn', one of {names} (scripted ones with parameters as name:key=value,...), a population "
                   f"(population:NAME[#PART] or FILE.json[#PART]) or a checkpoint path ending in .pt")
        if not self.learns and read_name(self.policy) is None:
            fail(self, "policy", allowed)
        check_strings(self, "policies", allowed="a list of policies, one per agent of the role, or [] to give "
                                                "every agent the role's policy")
        for spec in self.policies:
            if spec != "learn" and read_name(spec) is None:
                fail(self, "policies", f"{spec!r} is not a policy: each one {allowed}")
        check_bool(self, "share_network")
        if self.init is not None and not isinstance(self.init, str):
            fail(self, "init", "a checkpoint path (a string) or null")
        if self.init is not None and "learn" not in (self.policies or (self.policy,)):
            fail(self, "init", "warm-starting only applies to policy='learn'")
        check_number(self, "aux_coef", "a number in [0, 100]", between(0.0, 100.0))
        learns = "learn" in (self.policies or (self.policy,))
        if self.aux_target != "goal" and not (isinstance(self.aux_target, str) and learns
                                              and read_name(self.aux_target) is not None):
            fail(self, "aux_target", "'goal', or for policy='learn' the name of a policy with a belief over the goal "
                                     f"(e.g. 'bayes-people') whose belief the auxiliary head is distilled from")
        check_choice(self, "train_reward", ("env", "own"), "'env' (the env's reward) or 'own' (own block reward)")
        check_number(self, "wrong_weight", "a number in [0, 100]", between(0.0, 100.0))
        if self.wrong_weight != 1.0 and self.train_reward != "own":
            fail(self, "wrong_weight", "1.0 unless train_reward='own' (it weighs the agent's own wrong blocks)")
        check_number(self, "lr", "a number in (0, 1), or null to use ppo.lr", between(0.0, 1.0, True, True),
                     optional=True)
