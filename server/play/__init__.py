"""The play engine: every live game and waiting room of this process, behind one facade (``GameHub``).

Each job has its module over the state they share (``live.Live``): what a player may choose (``offer``), the
policy pools (AI followers and leaders) warmed, timed and freed (``pools``), the clock that steps real-time games
with one batched call per pool (``clock``), people joining, rejoining and leaving games (``sessions``), the waiting
rooms (``lobby``), and the end of a game: saved, its listeners told (``ending``). An application plugs in through
``source``: a game source that chooses people's games, and listeners told of each game's start and end (a study).
"""
