// The play WebSocket, shared by the play page and the study page: it sends a first message, hands each
// message on, and when the connection drops while a game is in play it rejoins that game a second later
// on a new socket. See docs/SERVER_PROTOCOL.md.

// handlers: onOpen(socket) for every socket opened (send on the latest), onMessage(msg), liveGame() (the game
// to rejoin, or null), onDrop() (say the connection was lost).
export function playSocket(firstMessage, handlers) {
  const socket = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/play`);
  handlers.onOpen(socket);
  socket.onopen = () => socket.send(JSON.stringify(firstMessage));
  socket.onmessage = (event) => handlers.onMessage(JSON.parse(event.data));
  socket.onclose = () => {
    const game = handlers.liveGame();
    if (!game) return;
    handlers.onDrop();
    setTimeout(() => playSocket({ type: "rejoin", game_id: game.game_id, token: game.token }, handlers), 1000);
  };
  return socket;
}
