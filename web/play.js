// The play page: the server owns the game; this page draws states and sends keys.
import { drawBoard, drawBelief, PALETTE } from "./board.js";

const $ = (id) => document.getElementById(id);
const KEYS = new Set(["ArrowUp", "ArrowDown", "ArrowLeft", "ArrowRight", "w", "a", "s", "d", "W", "A", "S", "D"]);
let socket = null, game = null, seq = 0, beliefHidden = false, lastState = null;

async function loadOptions() {
  const options = await (await fetch("/api/options")).json();
  fill($("follower"), options.followers, options.default_follower);
  fill($("preset"), options.presets, options.default_preset);
  $("tick-note").textContent = `real time runs at ${options.tick_hz} steps/s`;
  if (!options.show_belief) { $("belief-toggle").disabled = true; beliefHidden = true; }
}

function fill(select, values, chosen) {
  select.replaceChildren(...values.map((v) => new Option(v, v, v === chosen, v === chosen)));
}

function status(text, kind = "") {
  $("status").textContent = text;
  $("status").className = kind;
}

function connect(firstMessage) {
  const url = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/play`;
  socket = new WebSocket(url);
  socket.onopen = () => socket.send(JSON.stringify(firstMessage));
  socket.onmessage = (event) => onMessage(JSON.parse(event.data));
  socket.onclose = () => {
    if (game && !game.over && !game.replaced) {
      status("connection lost: rejoining...", "warn");
      setTimeout(() => connect({ type: "rejoin", game_id: game.game_id, token: game.token }), 1000);
    }
  };
}

function onMessage(msg) {
  if (msg.type === "welcome") {
    game = { ...msg, over: false };
    sessionStorage.setItem("colorgrid-game", JSON.stringify({ game_id: msg.game_id, token: msg.token }));
    $("setup").hidden = true;
    $("over").hidden = true;
    $("game").hidden = false;
    $("mode-label").textContent = msg.mode === "turn" ? "turn-based: the world moves when you do" : `real time, ${msg.tick_hz} steps/s`;
    $("follower-label").textContent = msg.follower;
    $("belief-panel").hidden = !msg.show_belief;
    status("your move: arrow keys or WASD");
  } else if (msg.type === "state") {
    lastState = msg;
    render(msg);
  } else if (msg.type === "game_over") {
    game.over = true;
    sessionStorage.removeItem("colorgrid-game");
    $("over").hidden = false;
    $("over-scores").textContent = `team ${fmt(msg.scores.team)} (you ${fmt(msg.scores.leader)}, follower ${fmt(msg.scores.follower)}) after ${msg.steps} steps`;
    const link = $("replay-link");
    link.hidden = !msg.replay_id;
    if (msg.replay_id) link.href = `/replay?id=${encodeURIComponent(msg.replay_id)}`;
    status(msg.reason === "complete" ? "game over" : `game ended: ${msg.reason}`);
  } else if (msg.type === "error") {
    status(`${msg.code}: ${msg.message}`, "error");
  } else if (msg.type === "replaced") {
    game.replaced = true;  // another tab rejoined this game: it plays there now, so do not take it back
    status("this game continues in another tab or window", "warn");
  } else if (msg.type === "full") {
    status(msg.message, "error");
    game = null;
  }
}

const fmt = (x) => (x > 0 ? "+" : "") + x;

function render(state) {
  const canvas = $("board");
  drawBoard(canvas, { height: game.height, width: game.width, ...state });
  canvas.dataset.leader = state.leader;  // agents' cells, for assistive tools and tests
  canvas.dataset.follower = state.follower;
  canvas.dataset.step = state.step;
  $("step").textContent = `${state.step} / ${state.horizon}`;
  $("left").textContent = `${state.horizon - state.step} steps left`;
  $("score-team").textContent = fmt(state.scores.team);
  $("score-leader").textContent = fmt(state.scores.leader);
  $("score-follower").textContent = fmt(state.scores.follower);
  $("goal-swatch").style.background = PALETTE[state.goal];
  $("goal-name").textContent = game.colors[state.goal];
  drawBelief($("belief"), beliefHidden ? null : state.belief, game.colors);
  const events = state.events.map((e) => e.switch !== undefined ? `goal switched to ${game.colors[e.switch]}`
    : `${e.agent} took ${game.colors[e.color]} (${e.goal ? "+" : "-"})`);
  if (events.length) $("events").textContent = events.join("; ");
}

document.addEventListener("keydown", (event) => {
  if (!KEYS.has(event.key) || !game || game.over || !socket || socket.readyState !== WebSocket.OPEN) return;
  event.preventDefault();
  socket.send(JSON.stringify({ type: "key", key: event.key, seq: seq++, t_client: performance.timeOrigin + performance.now() }));
});

$("start").addEventListener("click", () => {
  seq = 0;
  connect({ type: "new_game", follower: $("follower").value, preset: $("preset").value, mode: $("mode").value,
            horizon: $("horizon").value ? Number($("horizon").value) : null, show_belief: true });
});
$("again").addEventListener("click", () => { $("over").hidden = true; $("game").hidden = true; $("setup").hidden = false; game = null; });
$("quit").addEventListener("click", () => socket && socket.send(JSON.stringify({ type: "quit" })));
$("belief-toggle").addEventListener("change", (event) => {
  beliefHidden = !event.target.checked;
  if (lastState) render(lastState);
});

loadOptions().then(() => {
  const saved = sessionStorage.getItem("colorgrid-game");
  if (saved) connect({ type: "rejoin", ...JSON.parse(saved) });
});
