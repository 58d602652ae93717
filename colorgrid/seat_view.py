"""One seat's view of a batch's observations, as the Gymnasium and PettingZoo views hand it out: the planes every
seat shares, with the observer's own cell again as the last plane beyond the 1:1 team, and the seat's goal info; a
``Dict`` of the two, or one flat float32 vector for libraries whose default networks take no ``Dict``."""

from __future__ import annotations

import numpy as np


def seat_view(observation: np.ndarray, goal_info: np.ndarray, seat: int, num_colors: int, self_plane: bool,
              flatten: bool) -> dict[str, np.ndarray] | np.ndarray:
    """Seat ``seat``'s view of the batch's ``observation`` (``[B, C, H, W]``, shared by every seat) and
    ``goal_info`` (``[B, A, G]``). ``self_plane``: the observer's own cell plane (plane ``num_colors + seat``) again,
    last. Returns ``{"observation": [B, C', H, W], "goal_info": [B, G]}`` (new arrays), or with ``flatten``
    ``[B, C'*H*W + G]`` float32: the planes, then the goal."""
    if self_plane:
        planes = np.concatenate([observation, observation[:, num_colors + seat][:, None]], axis=1)
    else:
        planes = observation.copy()
    goal = goal_info[:, seat].copy()
    if not flatten:
        return {"observation": planes, "goal_info": goal}
    return np.concatenate([planes.reshape(len(planes), -1).astype(np.float32), goal], axis=1)
