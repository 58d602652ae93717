// The play page: the server owns the game; this page draws states and sends keys. What it offers and
// how it draws (followers, presets, modes, teams, keys, colors, agents) all come from the server. A team of
// several people meets in a room first (web/room.js draws it).
import { agentBadge, drawBoard, drawBelief, setLook } from "./board.js";
import { countdown } from "./countdown.js";
import { PlaySocket } from "./socket.js";
import { OwnMove } from "./predict.js";
import { plainEnding, plainError, setEndings, stepsMessage } from "./messages.js";
import { queryParam } from "./params.js";
import { drawBeliefs, markYou, openedRoom, plainRoomClosed, plainRoomError, setRoomWords, showAgents, showRoom,
         showScores, showSeats, whoIs } from "./room.js";
import { answerProbe, drawStated, followerSeat, probeRefused, seatHint, seatKey, seatRequest, showProbeChoice,
         showProbeConfidence, showSeatChoice, showStatedRecord, startSeat } from "./follower_seat.js";
import { GOAL_VIEW, MODE, ROLE, SEAT_STATUS } from "./sets.js";

const $ = (id) => document.getElementById(id);
const ARROWS = { ArrowUp: "↑", ArrowDown: "↓", ArrowLeft: "←", ArrowRight: "→" };
let options = null, game = null, room = null, seq = 0, own = null, beliefHidden = false, lastState = null;

async function loadOptions() {
  options = await (await fetch("/api/options")).json();
  setLook(options.look);
  setEndings(options.endings);
  setRoomWords(options.room_words);
  fill($("team"), options.teams, options.teams[0].value);
  fill($("follower"), options.follower_info, options.default_follower);
  fill($("preset"), options.presets.map((v) => ({ value: v, label: v })), options.default_preset);
  fill($("mode"), options.modes, options.modes[0].value);
  $("horizon").max = options.horizon.max;
  for (const agent of options.look.agents) {  // the discs as the board draws them: yours ringed, as on the board
    for (const el of document.querySelectorAll(`[data-symbol="${agent.name}"]`)) {
      const badge = agentBadge(agent);
      if (agent.role === (el.closest("#who-assists") ? "follower" : "leader")) badge.classList.add("you-badge");
      el.replaceChildren(badge);
    }
  }
  $("move-keys").textContent = moveKeys(options.keys);
  showTeamChoice();
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

function chosenTeam() {
  return options.teams.find((t) => t.value === $("team").value);
}

function showTeamChoice() {
  // the followers that play in the chosen team, the AI leaders that may lead beside you in it, and what starting
  // it does
  const team = chosenTeam(), current = $("follower").value;
  showSeatChoice(options, team, fill);  // a team of one leader may seat you as its follower, beside an AI leader
  const assisting = followerSeat();
  const offered = options.follower_info.filter((f) => team.followers.includes(f.value));
  fill($("follower"), offered, team.followers.includes(current) ? current : team.followers[0]);
  $("follower-choice").hidden = aiFollowers(team) === 0;
  const leaders = options.leader_info.filter((l) => (team.leaders ?? []).includes(l.value));
  $("leader-choice").hidden = !leaders.length || assisting;
  fill($("leader"), [{ value: "", label: "another person (a room)" }, ...leaders], "");
  // what the setup card says of who is who and of the goal, for the seat chosen
  $("setup-title").textContent = assisting ? "Play the assistant" : "Lead the way";
  $("who-is-who").hidden = assisting;
  $("who-assists").hidden = !assisting;
  $("goal-help").hidden = assisting && $("goal-view").value === GOAL_VIEW.HIDDEN;
  $("stated-help").hidden = !assisting;
  // one person with several AI followers may give the second its own kind
  const mixed = aiFollowers(team) > 1 && !team.room;
  $("second-follower").hidden = !mixed;
  $("follower-heading").textContent = mixed ? "First AI partner" : "Your AI partner";
  if (mixed) fill($("follower-2"), [{ value: "", label: "the same kind" }, ...offered], "");
  showStart();
}

function aiFollowers(team) {
  // the AI followers a game of this team has: every follower, but the one you play in the follower seat
  return team.ai_followers - (followerSeat() ? 1 : 0);
}

function chosenLeader() {
  // the AI leader you lead beside (a team of several leaders), or "" (the other leaders are people: a room)
  return $("leader-choice").hidden ? "" : $("leader").value;
}

function inRoom(team) {
  return team.room && !chosenLeader();
}

function showStart() {
  // what starting the chosen team does, with or without an AI leader beside you
  const team = chosenTeam();
  const followers = team.ai_followers === 1 ? "one AI follower" : `${team.ai_followers} AI followers`;
  showFollower();
  $("start").textContent = inRoom(team) ? "Create a room" : "Start";
  $("team-help").textContent = followerSeat()
    ? `You assist an AI leader${aiFollowers(team) ? ", beside an AI follower" : ""}: the leader knows the goal; ` +
      `you ${$("goal-view").value === GOAL_VIEW.HIDDEN ? "do not, and work it out from what it does" : "see it too (a control)"}.`
    : inRoom(team)
    ? `You and ${team.people - 1 === 1 ? "another person" : `${team.people - 1} other people`} lead together ` +
      `(${followers}): create a room, send its link, and the game starts when everyone is ready. In turn-based ` +
      "play the world steps once every person has moved."
    : chosenLeader() ? `You lead beside an AI leader, who also knows the goal (${followers}).`
    : team.ai_followers > 1 ? `${team.ai_followers} AI partners assist you; each forms its own belief.` : "";
  $("team-help").hidden = !$("team-help").textContent;  // no empty bullet
}

function followerInfo(name) {
  return options.follower_info.find((f) => f.value === name) ?? { value: name, label: name, description: "", has_belief: true };
}

function leaderInfo(name) {
  return options.leader_info.find((l) => l.value === name) ?? { value: name, label: name, description: "" };
}

function showFollower() {
  const second = $("second-follower").hidden ? "" : $("follower-2").value;
  const leader = chosenLeader() ? `. The other leader: ${leaderInfo(chosenLeader()).description}.`
    : followerSeat() ? ` The AI leader: ${leaderInfo($("seat-leader").value).description}.` : "";
  const followers = $("follower-choice").hidden ? [] : [$("follower").value, second];
  $("follower-description").textContent = followers.filter(Boolean)
    .map((name) => followerInfo(name).description).join(" ") + leader;
}

function chosenFollowers() {
  // what a request names: every AI follower's kind, or one kind each when the second differs (none when you play the
  // only follower)
  if ($("follower-choice").hidden) return {};
  const second = $("second-follower").hidden ? "" : $("follower-2").value;
  return second ? { followers: [$("follower").value, second] } : { follower: $("follower").value };
}

function showPreset() {
  // the chosen setting's rewards and episode length
  const chosen = options.preset_settings[$("preset").value];
  $("goal-reward").textContent = `+${chosen.goal_reward}`;
  $("wrong-penalty").textContent = `−${chosen.wrong_penalty}`;
  $("horizon").placeholder = chosen.horizon;
}

function showMode() {
  $("mode-help").textContent = $("mode").value === MODE.REALTIME
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

// One connection, for the game or room of the moment (web/socket.js): only its messages count, it goes back to the
// game or room after a drop, and it is closed when the game ends or the page leaves the room.
const connection = new PlaySocket({
  onMessage,
  resume: () => (game && !game.over && !game.replaced ? { type: "rejoin", game_id: game.game_id, token: game.token }
    : room ? { type: "join_room", code: room.code } : null),
  onDrop: () => status("connection lost: rejoining...", "warn"),
  onUnanswered: () => {  // the game or room asked for may or may not have been made: start again from the setup
    backToSetup();
    status("The connection was lost before the game started: start again.", "error");
  },
});

function connect(firstMessage) {
  connection.start(firstMessage);  // the connection before (the last game's, or one whose game was refused) closes
}

function onRoom(msg) {
  const first = !room;
  room = msg;
  history.replaceState(null, "", msg.link);  // a reload joins the room again
  $("setup").hidden = true;
  $("over").hidden = true;
  $("game").hidden = true;
  $("room").hidden = false;
  room.ready = showRoom(msg, options);
  if (msg.starting_in_s) {  // real time: the server starts the game after this countdown
    countdown($("countdown"), msg.starting_in_s).then(() => {
      $("countdown").textContent = "go";
      setTimeout(() => { $("countdown").hidden = true; }, 700);
    });
  } else {
    $("countdown").hidden = true;  // a countdown under way stopped: someone left
  }
  if (msg.starting_in_s != null) status("everyone is ready: the game starts...");
  else if (!first) status("");
  else status(openedRoom(msg) ? "room open: send the link to the person you lead with"
    : "you joined the room: press Ready when you are");
}

function backToSetup(clearLink = true) {  // out of a room (or a game that was not made), back to the choices
  connection.close();
  room = null;
  if (clearLink) history.replaceState(null, "", "/");
  $("game").hidden = true;
  $("countdown").hidden = true;
  $("room").hidden = true;
  $("setup").hidden = false;
}

// What the page does with each message of the server, by its type (server/messages.py declares them); a type not
// listed here is left alone.
const HANDLERS = {
  room: onRoom,
  room_closed: onRoomClosed,
  welcome: onWelcome,
  state: onState,
  seats: (msg) => showSeats(game, msg.seats),
  game_over: onGameOver,
  error: onRefusal,
  full: onRefusal,
  replaced: onReplaced,
};

function onMessage(msg) {
  HANDLERS[msg.type]?.(msg);
}

function onRoomClosed(msg) {
  backToSetup();
  status(plainRoomClosed(msg), "error", `room_closed: ${msg.reason}: ${msg.message}`);
}

function onWelcome(msg) {
  // "you": the agent this person plays (a team's welcome names it; in 1:1 the leader)
  game = { ...msg, over: false, agent: msg.agent ?? msg.look.agents.find((a) => a.role === ROLE.LEADER).name };
  room = null;
  lastState = null;
  seq = msg.next_seq;  // keys number on across reloads and reconnects
  own = new OwnMove(msg, game.agent);  // this person's own moves, drawn before the server's state shows them
  $("events").textContent = "";
  if (location.search) history.replaceState(null, "", "/");  // a reload rejoins the game, not the room
  setLook(msg.look);
  sessionStorage.setItem("colorgrid-game", JSON.stringify({ game_id: msg.game_id, token: msg.token }));
  $("setup").hidden = true;
  $("room").hidden = true;
  $("over").hidden = true;
  $("game").hidden = false;
  $("quit").hidden = false;
  if (!$("countdown").hidden) {  // "go" stays a moment over the first board
    $("countdown").textContent = "go";
    setTimeout(() => { $("countdown").hidden = true; }, 700);
  }
  const mode = options.modes.find((m) => m.value === msg.mode)?.label ?? msg.mode;
  const together = msg.seats?.length > 1;  // turn-based with other people: a step once everyone has moved
  $("mode-label").textContent = msg.tick_hz ? `${mode}, ${msg.tick_hz} steps/s`
    : `${mode}: the world moves when ${together ? "everyone has moved" : "you do"}`;
  const kinds = [...new Set(Object.values(msg.followers ?? { follower: msg.follower }))].map(followerInfo);
  const follower = { label: kinds.map((k) => k.label).join(" + "), description: kinds.map((k) => k.description).join(" "),
                     has_belief: kinds.some((k) => k.has_belief) };
  const assisting = msg.seat === ROLE.FOLLOWER;  // you play the follower, beside an AI leader
  const followers = game.look.agents.filter((a) => a.role === ROLE.FOLLOWER).length - (assisting ? 1 : 0);
  $("follower-label").textContent = follower.label;
  $("follower-label").title = follower.description;
  $("partner-note").hidden = followers === 0;
  $("partner-note").firstChild.textContent = followers > 1 ? "your AI partners: " : "your AI partner: ";
  const leaders = [...new Set(Object.values(msg.leaders ?? {}))].map(leaderInfo);  // AI leaders beside you
  $("leader-note").hidden = !leaders.length;
  $("leader-words").textContent = assisting ? "the leader (AI)" : "the other leader (AI)";
  $("leader-label").textContent = leaders.map((l) => l.label).join(" + ");
  $("leader-label").title = leaders.map((l) => l.description).join(" ");
  showAgents(game);
  $("belief-whose").textContent = followers > 1 ? "your AI partners believe" : "your AI partner believes";
  $("belief-panel").hidden = !(msg.show_belief && follower.has_belief && followers > 0);
  if (!assisting) status(`your move: ${moveKeys(options.keys)}`);
  startSeat(game, (message) => connection.send(message), seatStatus);  // in the seat: the hint follows the probe
}

function onState(msg) {
  lastState = msg;
  render(msg);
  if (game.team && game.mode === MODE.TURN) {
    if (game.seat === ROLE.FOLLOWER) seatStatus(seatHint(game));
    else status(`your move: ${moveKeys(options.keys)}`);
  }
}

function onGameOver(msg) {
  game.over = true;
  connection.close();  // one connection a game (the server closes it too)
  sessionStorage.removeItem("colorgrid-game");
  $("quit").hidden = true;
  $("over").hidden = false;
  $("over-scores").textContent = `team ${fmt(msg.scores.team)} (${agentScores(msg.scores)}) after ${msg.steps} steps`;
  showStatedRecord(game, msg.stated);  // the follower seat: the goal's history against what you said
  const link = $("replay-link");
  link.hidden = !msg.replay_id;
  if (msg.replay_id) link.href = `/replay?id=${encodeURIComponent(msg.replay_id)}`;
  status(plainEnding(msg.reason), "", `game_over: ${msg.reason}`);
}

function onRefusal(msg) {
  // an error, or a full game or room: the game or room may not have been made
  const detail = msg.type === "full" ? `full: ${msg.message}` : `${msg.code}: ${msg.message}`;
  console.info(detail);
  if (game?.over) return;  // about a key on its way when the game ended: the game's end stays on screen
  if (msg.code === "bad_probe") probeRefused(game, plainError(msg, options.horizon.max));
  const roomWords = plainRoomError(msg);
  if (game && msg.code === "rejected" && connection.first?.type === "rejoin") game = null;  // lost while away
  if (!game && (!room || roomWords)) {  // the game or room was not made (or could not be resumed): back to the setup
    sessionStorage.removeItem("colorgrid-game");
    backToSetup(Boolean(roomWords));
  }
  status(roomWords ?? plainError(msg, options.horizon.max), "error", detail);
}

function onReplaced() {
  game.replaced = true;  // another tab rejoined this game: it plays there now, so do not take it back
  connection.close();
  status("this game continues in another tab or window", "warn");
}

const fmt = (x) => (x > 0 ? "+" : "") + x;

function seatStatus(hint) {
  // the follower seat's status line: your move and what to say, or (a probe open) how to answer it
  status(game.answering ? hint : `your move: ${moveKeys(options.keys)}. ${hint}`);
}

function named(name) {
  // "you", "your AI partner" (1:1); in a team with its label too: "L2 (the other person)", "F1 (your AI partner)"
  const symbol = game.look.agents.find((a) => a.name === name)?.symbol ?? name;
  return game.team ? `${symbol} (${whoIs(game, name)})` : whoIs(game, name);
}

function agentScores(scores) {
  // "you +1, your AI partner +2", in index order
  return game.look.agents.map((a) => `${named(a.name)} ${fmt(scores[a.name])}`).join(", ");
}

function render(state) {
  const canvas = $("board");
  const shown = own.shown(state);  // this person's own move at once (web/predict.js); the server's state corrects it
  const cell = drawBoard(canvas, { height: game.height, width: game.width, ...shown });
  for (const agent of game.look.agents) {
    canvas.dataset[agent.name] = state[agent.name];  // the server's cells of the agents, for assistive tools and tests
  }
  canvas.dataset.you = shown[game.agent];  // where this person's disc is drawn
  markYou(canvas, cell, game.width, shown[game.agent]);
  showScores(game, state.scores, fmt);
  canvas.dataset.step = state.step;
  $("step").textContent = `${state.step} / ${state.horizon}`;
  $("left").textContent = `${state.horizon - state.step} steps left`;
  $("score-team").textContent = fmt(state.scores.team);
  $("goal-swatch").style.background = state.goal == null ? "#999" : game.look.palette[state.goal];
  $("goal-name").textContent = state.goal == null ? "hidden from you" : game.colors[state.goal];
  drawStated(game, state);
  if (game.team) drawBeliefs($("belief"), beliefHidden ? null : state.beliefs, game, drawBelief);
  else drawBelief($("belief"), beliefHidden ? null : state.belief, game.colors);
  const events = state.events.map((e) => e.switch !== undefined ? `goal switched to ${game.colors[e.switch]}`
    : `${named(e.agent)} took ${game.colors[e.color]} (${e.goal ? "+" : "-"})`);
  if (events.length) $("events").textContent = events.join("; ");
}

function playing() {
  // a game this page plays, before its last step (a key after it moves nothing)
  return game && !game.over && !game.replaced && connection.ready
    && !(lastState && lastState.step >= lastState.horizon);
}

function pageEvent(event) {
  // the page hidden or shown, its window left or back: recorded in the replay (meta.page_events)
  if (!playing()) return;
  connection.send({ type: "page_event", event, visible: document.visibilityState === "visible",
                    t_client: performance.timeOrigin + performance.now() });
}

window.addEventListener("blur", () => pageEvent("blur"));
window.addEventListener("focus", () => pageEvent("focus"));
document.addEventListener("visibilitychange", () => pageEvent("visibilitychange"));

function keyMessage(key) {
  // a key (a move, or a color the follower seat states), numbered on with the others: every key message is this one
  return { type: "key", key, seq: seq++, t_client: performance.timeOrigin + performance.now() };
}

function sendKey(key) {
  return connection.send(keyMessage(key));
}

document.addEventListener("keydown", (event) => {
  if (!playing()) return;
  if (seatKey(game, event, sendKey, (message) => connection.send(message))) {  // the follower seat's own keys
    event.preventDefault();
    return;
  }
  if (!Object.hasOwn(options.keys, event.key)) return;
  event.preventDefault();
  const message = keyMessage(event.key);
  connection.send(message);
  own.press(event.key, message.seq);
  if (lastState) render(lastState);  // the move at once; the server's state corrects it
  if (game.team && game.mode === MODE.TURN && game.seats.filter((s) => s.status !== SEAT_STATUS.LEFT).length > 1) {
    status("waiting for the other person to move...");
  }
});

$("start").addEventListener("click", async () => {
  if (!$("horizon").validity.valid) {  // the server checks it too (the same words come back)
    status(stepsMessage(options.horizon.max), "error");
    return;
  }
  const team = chosenTeam(), leader = chosenLeader();
  const request = { type: inRoom(team) ? "create_room" : "new_game", team: team.value, ...chosenFollowers(),
                    ...(leader ? { leader } : {}), ...seatRequest(), preset: $("preset").value, mode: $("mode").value,
                    horizon: $("horizon").value ? Number($("horizon").value) : null, show_belief: true,
                    viewport: [window.innerWidth, window.innerHeight] };
  seq = 0;
  game = null;
  room = null;
  status("");
  if (request.mode === MODE.REALTIME && request.type === "new_game") {  // a room's countdown is the server's
    // The countdown runs before the game exists: the server steps a real-time world from its first
    // moment, so nothing moves, and no key counts, until "go".
    $("setup").hidden = true;
    await countdown($("countdown"));
    $("countdown").textContent = "go";
  }
  connect(request);
});
function joinRoom(code) {
  seq = 0;
  game = null;
  room = null;
  connect({ type: "join_room", code, viewport: [window.innerWidth, window.innerHeight] });
}

// A typed code opens the room's link, as a shared link does: behind HAProxy (several backends) the link is sent on
// to the backend holding the room, which a join over this page's socket might not reach.
$("join").addEventListener("click", () => {
  location.assign(`/?room=${encodeURIComponent($("join-code").value.trim())}`);
});
$("ready").addEventListener("click", () => connection.send({ type: "ready", ready: !room?.ready }));
$("leave-room").addEventListener("click", () => {
  connection.send({ type: "quit" });
  backToSetup();
  status("");
});
$("copy-link").addEventListener("click", () => navigator.clipboard?.writeText($("room-link").href));
$("team").addEventListener("change", showTeamChoice);
$("follower").addEventListener("change", showFollower);
$("follower-2").addEventListener("change", showFollower);
$("leader").addEventListener("change", showStart);
$("seat").addEventListener("change", showTeamChoice);
$("seat-leader").addEventListener("change", showFollower);
$("goal-view").addEventListener("change", showTeamChoice);
$("probe-kind").addEventListener("change", showProbeChoice);
$("probe-confidence").addEventListener("input", showProbeConfidence);
$("probe-answer").addEventListener("click", () => answerProbe(game, (message) => connection.send(message)));
$("preset").addEventListener("change", showPreset);
$("mode").addEventListener("change", showMode);
$("again").addEventListener("click", () => {
  $("over").hidden = true;
  $("game").hidden = true;
  $("setup").hidden = false;
  game = null;
  status("");  // the last game's end is not this one's
});
$("quit").addEventListener("click", () => connection.send({ type: "quit" }));
$("belief-toggle").addEventListener("change", (event) => {
  beliefHidden = !event.target.checked;
  if (lastState) render(lastState);
});

loadOptions().then(() => {
  const saved = sessionStorage.getItem("colorgrid-game");
  const code = queryParam("room");
  if (saved) connect({ type: "rejoin", ...JSON.parse(saved) });
  else if (code !== null) joinRoom(code);  // a shared room link, or a typed code (an empty one: the server says why)
});
