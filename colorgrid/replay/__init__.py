"""Replays: the file format, re-simulation and verification, recording, import and the index of a folder.

Beside them, imported by name: ``export`` (GIF and MP4), ``branch`` (what-if branches and rescoring) and
``human_follower`` (the measures of a person in the follower seat)."""

from colorgrid.replay.format import FORMAT_VERSION, SUFFIX, Replay, ReplayError, describe_agent, load, save
from colorgrid.replay.frames import import_frames
from colorgrid.replay.simulate import Verification, from_batch, replay_states, verify

__all__ = ["FORMAT_VERSION", "SUFFIX", "Replay", "ReplayError", "Verification", "describe_agent", "from_batch",
           "import_frames", "load", "replay_states", "save", "verify"]
