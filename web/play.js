// The play page: the server owns the game; this page draws states and sends keys. What it offers and
// how it draws (followers, presets, modes, keys, colors, agents) all come from the server.
import { drawBoard, drawBelief, setLook } from "./board.js";
import { countdown } from "./countdown.js";
import { playSocket } from "./socket.js";
import { plainEnding, plainError, stepsMessage } from "./messages.js";

const $ = (id) => document.getElementById(id);
const ARROWS = { ArrowUp: "↑", ArrowDown: "↓", ArrowLeft: "←", ArrowRight: "→" };
let options = null, socket = null, game = null, seq = 0, beliefHidden = false, lastState = null;

async function loadOptions() {
  options = await (await fetch("/api/options")).json();
  setLook(options.look);
  fill($("follower"), options.follower_info, options.default_follower);
  fill($("preset"), options.presets.map((v) => ({ value: v, label: v })), options.default_preset);
  fill($("mode"), options.modes, options.modes[0].value);
  $("horizon").max = options.horizon.max;
  for (const agent of options.look.agents) {
    for (const el of document.querySelectorAll(`[data-symbol="${agent.name}"]`)) el.textContent = agent.symbol;
  }
  $("move-keys").textContent = moveKeys(options.keys);
  showFollower();
  showPreset();
  showMode();
  $("tick-note").textContent = `real time runs at ${options.tick_hz} steps/s`;
  if (!options.show_belief) { $("belief-toggle").disabled = true; beliefHidden = true; }
}

function moveKeys(keys) {
  // "↑ or W, ↓ or S, ← or A, → or D": each action's keys, in the actions' order
  const byAction = new Map();
  for (const [key, action] of Object.entries(keys).sort((a, b) => a[1] - b[1])) {
    const shown = ARROWS[key] ?? key.toUpperCase();
    byAction.set(action, [...new Set([...(byAction.get(action) ?? []), shown])]);
  }
  return [...byAction.values()].map((names) => names.join(" or ")).join(", ");
}

function followerInfo(name) {
  return options.follower_info.find((f) => f.value === name) ?? { value: name, label: name, description: "", has_belief: true };
}

function showFollower() {
  $("follower-description").textContent = followerInfo($("follower").value).description;
}

function showPreset() {
  // the chosen setting's rewards and episode length
  const chosen = options.preset_settings[$("preset").value];
  $("goal-reward").textContent = `+${chosen.goal_reward}`;
  $("wrong-penalty").textContent = `−${chosen.wrong_penalty}`;
  $("horizon").placeholder = chosen.horizon;
}

function showMode() {
  $("mode-help").textContent = $("mode").value === "realtime"
    ? `Real time: the world moves ${options.tick_hz} steps a second whether you press a key or not ` +
      "(without a key you stay put). A 3-2-1 countdown comes first."
    : "Turn-based: the world takes one step each time you move.";
}

function fill(select, items, chosen) {
  select.replaceChildren(...items.map(({ value, label, description }) => {
    const option = new Option(label, value, value === chosen, value === chosen);
    if (description) option.title = description;
    return option;
  }));
}

function status(text, kind = "", detail = "") {
  $("status").textContent = text;
  $("status").className = kind;
  $("status").title = detail;  // the protocol's words, for researchers
}

function connect(firstMessage) {
  playSocket(firstMessage, {
    onOpen: (opened) => { socket = opened; },
    onMessage,
    liveGame: () => (game && !game.over && !game.replaced ? game : null),
    onDrop: () => status("connection lost: rejoining...", "warn"),
  });
}

function onMessage(msg) {
  if (msg.type === "welcome") {
    game = { ...msg, over: false };
    setLook(msg.look);
    sessionStorage.setItem("colorgrid-game", JSON.stringify({ game_id: msg.game_id, token: msg.token }));
    $("setup").hidden = true;
    $("over").hidden = true;
    $("game").hidden = false;
    $("quit").hidden = false;
    if (!$("countdown").hidden) {  // "go" stays a moment over the first board
      $("countdown").textContent = "go";
      setTimeout(() => { $("countdown").hidden = true; }, 700);
    }
    const mode = options.modes.find((m) => m.value === msg.mode)?.label ?? msg.mode;
    $("mode-label").textContent = msg.tick_hz ? `${mode}, ${msg.tick_hz} steps/s` : `${mode}: the world moves when you do`;
    const follower = followerInfo(msg.follower);
    $("follower-label").textContent = follower.label;
    $("follower-label").title = follower.description;
    $("belief-panel").hidden = !(msg.show_belief && follower.has_belief);
    status(`your move: ${moveKeys(options.keys)}`);
  } else if (msg.type === "state") {
    lastState = msg;
    render(msg);
  } else if (msg.type === "game_over") {
    game.over = true;
    sessionStorage.removeItem("colorgrid-game");
    $("quit").hidden = true;
    $("over").hidden = false;
    const [you, partner] = game.look.agents;  // in index order: the leader (the player), then the follower
    $("over-scores").textContent = `team ${fmt(msg.scores.team)} (you ${fmt(msg.scores[you.name])}, ` +
      `${partner.name} ${fmt(msg.scores[partner.name])}) after ${msg.steps} steps`;
    const link = $("replay-link");
    link.hidden = !msg.replay_id;
    if (msg.replay_id) link.href = `/replay?id=${encodeURIComponent(msg.replay_id)}`;
    status(plainEnding(msg.reason), "", `game_over: ${msg.reason}`);
  } else if (msg.type === "error" || msg.type === "full") {
    const detail = msg.type === "full" ? `full: ${msg.message}` : `${msg.code}: ${msg.message}`;
    console.info(detail);
    if (!game) {  // the game was not made (or could not be resumed): back to the setup
      sessionStorage.removeItem("colorgrid-game");
      $("countdown").hidden = true;
      $("setup").hidden = false;
    }
    status(plainError(msg, options.horizon.max), "error", detail);
  } else if (msg.type === "replaced") {
    game.replaced = true;  // another tab rejoined this game: it plays there now, so do not take it back
    status("this game continues in another tab or window", "warn");
  }
}

const fmt = (x) => (x > 0 ? "+" : "") + x;

function render(state) {
  const canvas = $("board");
  drawBoard(canvas, { height: game.height, width: game.width, ...state });
  for (const agent of game.look.agents) {
    canvas.dataset[agent.name] = state[agent.name];  // agents' cells, for assistive tools and tests
    $(`score-${agent.name}`).textContent = fmt(state.scores[agent.name]);
  }
  canvas.dataset.step = state.step;
  $("step").textContent = `${state.step} / ${state.horizon}`;
  $("left").textContent = `${state.horizon - state.step} steps left`;
  $("score-team").textContent = fmt(state.scores.team);
  $("goal-swatch").style.background = game.look.palette[state.goal];
  $("goal-name").textContent = game.colors[state.goal];
  drawBelief($("belief"), beliefHidden ? null : state.belief, game.colors);
  const events = state.events.map((e) => e.switch !== undefined ? `goal switched to ${game.colors[e.switch]}`
    : `${e.agent} took ${game.colors[e.color]} (${e.goal ? "+" : "-"})`);
  if (events.length) $("events").textContent = events.join("; ");
}

document.addEventListener("keydown", (event) => {
  if (!game || game.over || !socket || socket.readyState !== WebSocket.OPEN || !Object.hasOwn(options.keys, event.key)) return;
  event.preventDefault();
  socket.send(JSON.stringify({ type: "key", key: event.key, seq: seq++, t_client: performance.timeOrigin + performance.now() }));
});

$("start").addEventListener("click", async () => {
  if (!$("horizon").validity.valid) {  // the server checks it too (the same words come back)
    status(stepsMessage(options.horizon.max), "error");
    return;
  }
  const request = { type: "new_game", follower: $("follower").value, preset: $("preset").value, mode: $("mode").value,
                    horizon: $("horizon").value ? Number($("horizon").value) : null, show_belief: true,
                    viewport: [window.innerWidth, window.innerHeight] };
  seq = 0;
  game = null;
  status("");
  if (socket) {  // the last game's socket, or one whose game was refused: it has nothing more to say
    socket.onclose = socket.onmessage = null;
    socket.close();
  }
  if (request.mode === "realtime") {
    // The countdown runs before the game exists: the server steps a real-time world from its first
    // moment, so nothing moves, and no key counts, until "go".
    $("setup").hidden = true;
    await countdown($("countdown"));
    $("countdown").textContent = "go";
  }
  connect(request);
});
$("follower").addEventListener("change", showFollower);
$("preset").addEventListener("change", showPreset);
$("mode").addEventListener("change", showMode);
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
