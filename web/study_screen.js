// What the study page measures for the study's [screening] before consent (the device, the window, round trips over
// the play socket), and the round trips it measures during a game for [exclusions] round_trip_ms. The server decides:
// the page only measures and reports. See docs/STUDIES.md, "Screening and exclusions".

const PLAY_PING_MS = 2000;  // during a game, a ping this often (the first at once)

// Whether the device has a touch screen and no mouse or trackpad: a phone or a tablet.
function touchOnly() {
  const touch = navigator.maxTouchPoints > 0 || matchMedia("(any-pointer: coarse)").matches;
  return touch && !matchMedia("(any-pointer: fine)").matches;
}

// The round trips of `count` pings, one after another, over a play socket of their own (ms).
function roundTrips(count) {
  return new Promise((resolve) => {
    const socket = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/play`);
    const times = [];
    let sent = 0;
    const ping = () => { sent = performance.now(); socket.send(JSON.stringify({ type: "ping" })); };
    const done = () => { socket.close(); resolve(times); };
    socket.addEventListener("open", ping);
    socket.addEventListener("message", (event) => {
      if (JSON.parse(event.data).type !== "pong") return;
      times.push(performance.now() - sent);
      if (times.length < count) ping(); else done();
    });
    socket.addEventListener("error", done);  // fewer round trips than asked: the server says it could not measure
    socket.addEventListener("close", () => resolve(times));
  });
}

// The page's `screen` for the join request: {touch_only, viewport, round_trips_ms}.
export async function measureScreen(pings) {
  return { touch_only: touchOnly(), viewport: [window.innerWidth, window.innerHeight],
           round_trips_ms: await roundTrips(pings) };
}

// Pings during a game over its connection, each carrying the round trip of the one before (the server keeps them).
export class PlayPings {
  constructor(send) {
    this.send = send;  // sends a message on the game's connection; false when it is not open
    this.timer = null;
    this.sent = null;
    this.measured = null;
  }

  start() {
    this.stop();
    this.ping();
  }

  ping() {
    this.sent = performance.now();
    const message = { type: "ping" };
    if (this.measured !== null) message.round_trip_ms = this.measured;
    this.send(message);
    this.measured = null;
  }

  // A pong arrived: the round trip goes with the next ping (at once for the first, then every PLAY_PING_MS).
  pong() {
    if (this.sent === null) return;
    const first = this.timer === null;
    this.measured = Math.round((performance.now() - this.sent) * 1000) / 1000;
    this.sent = null;
    if (first) {
      this.ping();
      this.timer = setInterval(() => this.ping(), PLAY_PING_MS);
    }
  }

  stop() {
    clearInterval(this.timer);
    this.timer = null;
    this.sent = null;
    this.measured = null;
  }
}
