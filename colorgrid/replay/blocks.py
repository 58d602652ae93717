"""The board's blocks as text: one character per cell in row-major order, ``'.'`` for none or the color's digit
(``"..0.2.1"``). Replay frames (``frames.blocks``), the timeline's boards and the play server's ``state``
message all carry it; this is where it is written and read."""

from __future__ import annotations

import numpy as np

EMPTY = "."
"""A cell without a block."""


def encode_blocks(colors: np.ndarray) -> str:
    """``[H*W]`` block colors (-1: none) -> the blocks string (``'.'`` or the color's digit per cell)."""
    codes = np.where(colors < 0, ord(EMPTY), np.asarray(colors) + ord("0"))
    return codes.astype(np.uint8).tobytes().decode("ascii")


def decode_blocks(text: str) -> np.ndarray:
    """The blocks string -> ``[H*W]`` int64 block colors, -1 where a cell holds none."""
    codes = np.frombuffer(text.encode("ascii"), dtype=np.uint8).astype(np.int64) - ord("0")
    return np.where(codes < 0, -1, codes)
