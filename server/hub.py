"""The game hub at its first address: the play engine now lives in ``server.play`` (its facade ``server.play.hub``)."""

from server.play.hub import Client, GameHub, ServerFull

__all__ = ["Client", "GameHub", "ServerFull"]
