"""Networks loaded once per file version and shared: an object owned by whoever loads many policies."""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path


class ModelCache:
    """Networks loaded once per file version and shared (read-only) by every policy made from them.

    Whoever loads many policies of the same files owns one: the trainer's policy loaders
    (``train/plugin.py``) do, so that the play server's follower pools share one network per
    checkpoint. The least recently used network is dropped beyond ``maxsize``.
    """

    def __init__(self, maxsize: int = 16):
        self.maxsize = maxsize
        self.models: OrderedDict[tuple, object] = OrderedDict()

    def get(self, path: str | Path, role: str | None):
        """The ``ActorCritic`` of ``role`` in the checkpoint at ``path``."""
        from train.policy import load_model  # torch is imported only when a network is asked for

        file = Path(path)
        key = (str(file.resolve()), file.stat().st_mtime_ns if file.is_file() else None, role)
        if key in self.models:
            self.models.move_to_end(key)
        else:
            self.models[key] = load_model(path, role)
            while len(self.models) > self.maxsize:
                self.models.popitem(last=False)
        return self.models[key]

    def clear(self) -> None:
        self.models.clear()
