// The play WebSocket of a page (the play page's and the study page's): one connection at a time, for the game
// (or room) the page is in. Only the live connection's messages reach the page: a connection the page closed, or
// one that was replaced, says nothing more, so an old connection closing is never taken for the live one dropping.
// When the live connection drops while there is a game or room to go back to, one new connection is opened at a
// time, after a wait that doubles (about 1 s, 2 s, 4 s, then 8 s at most; a little random, so that pages dropped
// together do not all come back at once), to rejoin the game or join the room again. The page closes the
// connection when its game ends (the server closes it too). See docs/SERVER_PROTOCOL.md.

const FIRST_WAIT_MS = 1000;
const MAX_WAIT_MS = 8000;
const SENT_AGAIN = ["rejoin", "join_room"];  // first messages sent again when the connection dropped unanswered

// handlers: onMessage(msg), each message of the live connection; resume(), the message that takes the page back
// to its game or room on a new connection (a rejoin, a join_room), or null when there is nothing to go back to;
// onDrop(waitMs), the live connection dropped and a new one follows in waitMs; onUnanswered(), the live connection
// dropped before the server answered a new_game or create_room: whether the game or room was made is not known,
// and it is not asked for again.
export class PlaySocket {
  constructor(handlers) {
    this.handlers = handlers;
    this.socket = null;  // the live connection, or null
    this.first = null;  // the message it opened with
    this.answered = false;  // whether the server has sent anything on it
    this.drops = 0;  // drops since a connection was last answered: the next wait is FIRST_WAIT_MS * 2^drops
    this.retry = null;  // the timer of the next connection
  }

  // The live connection is open and answered: keys and page events may go.
  get ready() {
    return this.answered && this.socket?.readyState === WebSocket.OPEN;
  }

  // A new game, room or rejoin: the connection before (if any) is closed first.
  start(firstMessage) {
    this.close();
    this.drops = 0;
    this.open(firstMessage);
  }

  send(message) {
    if (!this.ready) return false;
    this.socket.send(JSON.stringify(message));
    return true;
  }

  // The game is over, or the page is done with it: nothing more is heard from this connection.
  close() {
    clearTimeout(this.retry);
    this.retry = null;
    const socket = this.socket;
    this.socket = null;
    if (socket && socket.readyState <= WebSocket.OPEN) socket.close(1000);
  }

  open(firstMessage) {
    const socket = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/play`);
    Object.assign(this, { socket, first: firstMessage, answered: false });
    socket.onopen = () => {
      if (socket === this.socket) socket.send(JSON.stringify(firstMessage));
    };
    socket.onmessage = (event) => {
      if (socket !== this.socket) return;
      this.answered = true;
      this.drops = 0;
      this.handlers.onMessage(JSON.parse(event.data));
    };
    socket.onclose = () => {
      if (socket !== this.socket) return;
      this.socket = null;
      const unanswered = !this.answered && SENT_AGAIN.includes(this.first.type) ? this.first : null;
      const again = this.handlers.resume() ?? unanswered;
      if (again) {
        const wait = Math.round(Math.min(MAX_WAIT_MS, FIRST_WAIT_MS * 2 ** this.drops++) * (0.9 + 0.2 * Math.random()));
        console.info(`play socket: connection lost; connecting again in ${wait} ms (attempt ${this.drops})`);
        this.handlers.onDrop(wait);
        this.retry = setTimeout(() => {
          this.retry = null;
          this.open(this.handlers.resume() ?? again);
        }, wait);
      } else if (!this.answered) {
        this.handlers.onUnanswered?.();
      }
    };
  }
}
