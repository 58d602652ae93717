// The play WebSocket, shared by the play page and the study page: it sends a first message, hands each
// message on, and when the connection drops while a game is in play it rejoins that game a second later
// on a new socket (or, while waiting in a room, joins the room again). See docs/SERVER_PROTOCOL.md.

// handlers: onOpen(socket) for every socket opened (send on the latest), onMessage(msg), liveGame() (the game
// to rejoin, or null), liveRoom() (optional: the code of the room waited in, or null), onDrop() (say the
// connection was lost).
export function playSocket(firstMessage, handlers) {
  const socket = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/play`);
  handlers.onOpen(socket);
  socket.onopen = () => socket.send(JSON.stringify(firstMessage));
  socket.onmessage = (event) => handlers.onMessage(JSON.parse(event.data));
  socket.onclose = () => {
    const game = handlers.liveGame();
    const room = game ? null : handlers.liveRoom?.() ?? null;
    if (!game && !room) return;
    handlers.onDrop();
    const again = game ? { type: "rejoin", game_id: game.game_id, token: game.token }
      : { type: "join_room", code: room };
    setTimeout(() => playSocket(again, handlers), 1000);
  };
  return socket;
}
