"""A person's departures around any leader policy: a trained leader that notices switches late, slips, hesitates.

``person:base=ippo-leader,slip=0.1,notice_delay=3`` is the IPPO leader with the departures of a ``PersonStyle``
(``colorgrid.policies.people``), so that a follower can be trained beside noisy or slow versions of trained leaders
as well as of A*. The departures are the person leader's own (``PersonDepartures``), around the base instead of A*:

- the base is shown the goal the person pursues (``AgentInput.goal_info`` is the one-hot of that color): the old
  goal for ``notice_delay`` steps after a switch, a wrong color after a ``wrong_pickup`` draw until it collects a
  block;
- its action is then changed by ``detour``, ``hesitate`` and ``slip`` as the person leader's is.

``rationality`` (Boltzmann moves over A* distances) is the A* leader's alone: ``PersonStyle`` refuses it with another
base. ``make_policy`` builds the base by its name and checks that it is a leader.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from colorgrid.config import EnvConfig
from colorgrid.policies.base import AgentInput, Policy, PolicyOutput
from colorgrid.policies.people import PERSON, PersonDepartures, PersonStyle


class StyledLeader(PersonDepartures):
    """The leader policy ``base`` with the departures of ``style`` (``style.base`` names it; not A*: that is
    ``PersonLeader``). The base keeps its own memory and random generator, reset with this policy's seed, so that
    with every departure off it takes the base's own actions; ``state_dict`` holds both."""

    name = PERSON

    def __init__(self, base: Policy, style: PersonStyle):
        if style.around_astar:
            raise ValueError("a person around A* is PersonLeader (person:..., without base)")
        self.base, self.style = base, style

    def describe(self) -> dict:
        """The person's policy and style (its ``base`` the name asked for), and the base's own description."""
        return {"policy": self.name, "base": self.base.describe(), "params": self.style.described()}

    def reset(self, config: EnvConfig, num_envs: int, agent_index: int, seed: int = 0) -> None:
        super().reset(config, num_envs, agent_index, seed)
        self.base.reset(config, num_envs, agent_index, seed)
        self.rng = np.random.default_rng([seed, agent_index, 7])  # the person leader's: the same draws
        self.reset_departures(num_envs)

    def see_team(self, policies: list[Policy]) -> None:
        self.base.see_team(policies)

    def act(self, inp: AgentInput, rows=None) -> PolicyOutput:
        """The base's action toward the pursued color, changed by the departures; the base's belief, if any."""
        rows = self._rows(rows)
        _, pursued, u = self.pursue(inp, rows)
        shown = np.eye(self.config.num_colors, dtype=inp.goal_info.dtype)[pursued]
        out = self.base.act(dataclasses.replace(inp, goal_info=shown), rows)
        return PolicyOutput(self.depart(np.array(out.actions, dtype=np.int64), u, rows), out.goal_probs)

    def state_dict(self) -> dict:
        """The departures' state and generator, and under ``base`` the base's own (its recurrent state, generator)."""
        return {**super().state_dict(), "base": self.base.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.base.load_state_dict(state["base"])

