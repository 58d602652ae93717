"""Replays: the file format, re-simulation and verification, recording, import and the index of a folder."""

from colorgrid.replay.format import FORMAT_VERSION, SUFFIX, Replay, ReplayError, describe_agent, load, save
from colorgrid.replay.frames import import_frames
from colorgrid.replay.simulate import Verification, from_batch, replay_states, verify

__all__ = ["FORMAT_VERSION", "SUFFIX", "Replay", "ReplayError", "Verification", "describe_agent", "from_batch",
           "import_frames", "load", "replay_states", "save", "verify"]
