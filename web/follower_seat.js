// The follower seat on the play page: the person plays the assistant beside an AI leader and works out the goal.
// This module draws what that seat adds: its choices in the setup card (the AI leader, whether the goal is hidden,
// the questions), the sentence that says who you are and what you are asked to do, one swatch per color to say which
// color you believe is the goal (or its number key), and the probe's question ("which color is the goal now, and how
// sure are you?"). The server owns all of it: the seats, leaders, goal views and probe kinds come from /api/options,
// the belief keys and the open probe from the welcome and each state (docs/SERVER_PROTOCOL.md, "The follower seat").
import { agentBadge } from "./board.js";
import { GOAL_VIEW, MODE, ROLE } from "./sets.js";

const $ = (id) => document.getElementById(id);

/** The probe dialog and the stated-belief panel, the same on the play page and the study page: put into each
 * page's #belief-controls when this module loads, before the pages' own code looks them up. Both sit in one slot, as
 * tall as the taller of them: the probe opens over the statement panel and nothing on the page moves. */
const BELIEF_CONTROLS = `
  <div id="belief-slot" class="belief-slot" hidden>
  <div id="probe" class="probe" role="dialog" aria-labelledby="probe-question" aria-live="assertive" hidden>
    <h3 id="probe-question">Which color is the goal now, and how sure are you?</h3>
    <p class="note"><span id="probe-step"></span>: <span id="probe-note"></span></p>
    <p class="note" id="probe-keys"></p>
    <div id="probe-colors"></div>
    <label>How sure are you? <input id="probe-confidence" type="range" min="34" max="100" step="1">
      <b id="probe-percent"></b></label>
    <button id="probe-answer" disabled>Answer</button>
    <p class="problem" id="probe-problem" aria-live="polite"></p>
  </div>
  <div id="stated-panel" hidden>
    <p class="note" id="stated-task"></p>
    <div id="stated-swatches" role="group" aria-label="the color you believe is the goal"></div>
    <p class="note" id="stated-now" aria-live="polite"></p>
  </div>
  </div>`;
const slot = document.getElementById("belief-controls");
if (slot) slot.outerHTML = BELIEF_CONTROLS;


// ---------------------------------------------------------------- the setup card
// The seat menu for the chosen team, and the follower seat's own choices when it is chosen.
export function showSeatChoice(options, team, fill) {
  const seats = options.seats.filter((s) => (team.seats ?? ["leader"]).includes(s.value));
  const current = $("seat").value;
  fill($("seat"), seats, seats.some((s) => s.value === current) ? current : "leader");
  $("seat-choice").hidden = seats.length < 2;
  const leaders = options.leader_info.filter((l) => (team.follower_seat_leaders ?? []).includes(l.value));
  const chosenLeader = $("seat-leader").value;
  fill($("seat-leader"), leaders, leaders.some((l) => l.value === chosenLeader) ? chosenLeader : leaders[0]?.value);
  if (!$("goal-view").options.length) fill($("goal-view"), options.goal_views, options.goal_views[0].value);
  if (!$("probe-kind").options.length) fill($("probe-kind"), options.probe_kinds, options.probe_kinds[0].value);
  showProbeChoice();
  $("follower-seat").hidden = !followerSeat();
}

export function followerSeat() {
  return !$("seat-choice").hidden && $("seat").value === ROLE.FOLLOWER;
}

export function showProbeChoice() {
  $("probe-steps-label").hidden = $("probe-kind").value !== "steps";
  $("probe-rate-label").hidden = $("probe-kind").value !== "random";
}

// What a new_game asks for the follower seat (nothing for a leader's): the server checks every value.
export function seatRequest() {
  if (!followerSeat()) return {};
  const kind = $("probe-kind").value;
  const probes = kind === "steps" ? `steps:${$("probe-steps").value.replace(/\s/g, "")}`
    : kind === "random" ? `random:${$("probe-rate").value}` : "none";
  return { seat: "follower", leader: $("seat-leader").value, goal: $("goal-view").value, probes };
}

// ---------------------------------------------------------------- in a game
// At the welcome of a game in the follower seat: the sentence saying who you are, the goal's fate, what to do; the
// swatches (with their keys); the probe's color buttons and its confidence range (chance to 100%).
// `onHint(words)`: the page's hint, called with what to do now (say the goal, or answer the probe) whenever it changes.
export function startSeat(game, send, onHint = () => {}) {
  const seated = game.seat === ROLE.FOLLOWER;
  $("belief-slot").hidden = !seated;
  $("stated-panel").hidden = !seated;
  $("probe").hidden = true;
  game.answering = null;
  game.onHint = onHint;
  if (!seated) return;
  const you = game.look.agents.find((a) => a.name === game.agent);
  const leaders = game.look.agents.filter((a) => a.role === ROLE.LEADER);
  const hidden = game.goal_view === GOAL_VIEW.HIDDEN;
  const task = $("stated-task");
  task.replaceChildren("You are ", ringed(agentBadge(you)), ", the assistant. The AI leader ",
    ...leaders.map((l) => agentBadge(l)), " knows the goal color", hidden ? "; it is hidden from you. " : ". ",
    hidden ? "Watch what the leader does, work out which color it is after, and say so: "
      : "The goal is shown to you in this game (a control). Say which color you believe is the goal: ",
    `press ${Object.keys(game.belief_keys).join(", ")} or click a color. Change it whenever you change your mind.`);
  $("stated-swatches").replaceChildren(...game.colors.map((name, k) => {
    const button = document.createElement("button");
    const key = Object.keys(game.belief_keys).find((key) => game.belief_keys[key] === k);
    button.className = "stated-color";
    button.dataset.color = k;
    button.style.borderColor = game.look.palette[k];
    const swatch = `<span class="swatch" style="background:${game.look.palette[k]}"></span>`;
    button.innerHTML = `${swatch} ${name} <kbd>${key}</kbd>`;
    button.addEventListener("click", () => {
      if (send({ type: "belief", color: k, t_client: now() })) showStated(game, k);
    });
    return button;
  }));
  $("probe-confidence").min = Math.ceil(100 * game.confidence_min);  // chance: the answer is your best guess
  $("probe-colors").replaceChildren(...game.colors.map((name, k) => {
    const button = document.createElement("button");
    const key = Object.keys(game.belief_keys).find((key) => game.belief_keys[key] === k);
    button.className = "probe-color";
    button.dataset.color = k;
    button.innerHTML = `<span class="swatch" style="background:${game.look.palette[k]}"></span> ${name} <kbd>${key}</kbd>`;
    button.addEventListener("click", () => pickProbeColor(game, k));
    return button;
  }));
  $("probe-note").textContent = game.mode === MODE.TURN ? "The game waits for your answer."
    : "The game goes on while you answer.";
  $("probe-keys").textContent = probeKeys(game);
  // the closed probe holds the widest words it may show, so that the slot keeps one height when it opens
  $("probe-step").textContent = `step ${game.horizon}`;
  $("probe-percent").textContent = "100%";
  showStated(game, null);
  onHint(seatHint(game));
}

function probeKeys(game) {
  // "Keys: 1, 2, 3 choose the color (or click one); ← → set how sure you are; Enter answers." The color keys are the
  // server's (welcome.belief_keys); in real time the arrows still move you, and the slider sets the confidence.
  return `Keys: ${Object.keys(game.belief_keys).join(", ")} choose the color (or click one); ${sureKeys(game)}; ` +
    "Enter answers.";
}

function sureKeys(game) {
  return game.mode === MODE.TURN ? "\u2190 \u2192 set how sure you are" : "the slider sets how sure you are";
}

// What the person is asked to do now, in a sentence: answer the open probe, or say the goal whenever they like.
export function seatHint(game) {
  const keys = Object.keys(game.belief_keys).join(", ");
  return game.answering ? `Answer the question: ${keys} choose the color, ${sureKeys(game)}, Enter answers.`
    : `Say which color you believe is the goal with ${keys} or a click on a color.`;
}

function ringed(badge) {
  badge.classList.add("you-badge");
  return badge;
}

const now = () => performance.timeOrigin + performance.now();

function showStated(game, color) {
  game.stated = color;
  for (const button of document.querySelectorAll(".stated-color")) {
    button.classList.toggle("chosen", Number(button.dataset.color) === color);
    button.setAttribute("aria-pressed", String(Number(button.dataset.color) === color));
  }
  $("stated-now").textContent = color == null ? "You have not said which color you believe is the goal yet."
    : `You said the goal is ${game.colors[color]}.`;
}

// Each state: your stated color as the server has it, and the probe it asks (shown until you answer it).
export function drawStated(game, state) {
  if (game.seat !== ROLE.FOLLOWER) return;
  // the server's word, unless this page said another color since (its state may have been on its way)
  if (state.stated !== game.stated && !game.sentSinceState) showStated(game, state.stated);
  game.sentSinceState = false;
  const probe = state.probe;
  if (probe && game.answered !== probe.id) {
    if (game.answering?.id !== probe.id) openProbe(game, probe);
  } else if (!probe && game.answering) {
    closeProbe(game);  // real time: a next probe, or the end, closed it
  }
}

function openProbe(game, probe) {
  game.answering = { id: probe.id, color: null };
  $("probe-step").textContent = `step ${probe.step}`;
  const range = $("probe-confidence");  // each question starts halfway between a guess and certain
  range.value = Math.round((Number(range.min) + 100) / 2);
  showProbeConfidence();
  for (const button of document.querySelectorAll(".probe-color")) button.classList.remove("chosen");
  $("probe-answer").disabled = true;
  $("probe-problem").textContent = "";
  $("probe").hidden = false;
  $("belief-slot").classList.add("asking");
  game.onHint?.(seatHint(game));
}

function closeProbe(game) {
  game.answering = null;
  $("probe").hidden = true;
  $("belief-slot").classList.remove("asking");
  game.onHint?.(seatHint(game));
}

function pickProbeColor(game, color) {
  if (!game.answering) return;
  game.answering.color = color;
  for (const button of document.querySelectorAll(".probe-color")) {
    button.classList.toggle("chosen", Number(button.dataset.color) === color);
  }
  $("probe-answer").disabled = false;
}

// The probe's answer, sent: its color and confidence (a probability). The server's error (bad_probe) reopens it.
export function answerProbe(game, send) {
  const open = game.answering;
  if (!open || open.color == null) return;
  const confidence = Number($("probe-confidence").value) / 100;
  if (!send({ type: "probe_answer", probe: open.id, color: open.color, confidence, t_client: now() })) return;
  game.answered = open.id;
  game.sentSinceState = true;
  showStated(game, open.color);
  closeProbe(game);
}

// A refused answer: the same probe asks again, with the server's reason in words.
export function probeRefused(game, words) {
  if (game.answered == null) return;
  const id = game.answered;
  game.answered = null;
  openProbe(game, { id, step: $("probe-step").textContent.replace("step ", "") });
  $("probe-problem").textContent = words;
}

// A key in the follower seat: while the probe asks, a number key picks its color and Enter answers (a move waits in
// turn-based play, goes on in real time); otherwise a number key says which color you believe is the goal (sent as a
// key, numbered with the moves). True when handled here.
export function seatKey(game, event, sendKey, send) {
  if (game.seat !== ROLE.FOLLOWER) return false;
  const color = game.belief_keys[event.key];
  if (game.answering) {
    const nudge = { ArrowLeft: -1, ArrowRight: 1 }[event.key];
    if (color !== undefined) pickProbeColor(game, color);
    else if (event.key === "Enter") answerProbe(game, send);
    else if (nudge && game.mode === MODE.TURN) nudgeConfidence(nudge * 5);  // real time: the arrows still move you
    else return game.mode === MODE.TURN;
    return true;
  }
  if (color === undefined) return false;
  if (sendKey(event.key)) {
    game.sentSinceState = true;
    showStated(game, color);
  }
  return true;
}

function nudgeConfidence(by) {
  const range = $("probe-confidence");
  range.value = Math.max(Number(range.min), Math.min(100, Number(range.value) + by));
  showProbeConfidence();
}

export function showProbeConfidence() {
  $("probe-percent").textContent = `${$("probe-confidence").value}%`;
}

// ---------------------------------------------------------------- the game's end
// The game-over card in the follower seat: the goal at each step against the color the person had said (a strip of
// each, the answered probes as dots under the step they were answered at, ringed in black when right), and how well
// they read it (game_over's `stated`: the server's measures). Hidden for a game without one.
export function showStatedRecord(game, record) {
  $("over-stated").hidden = !record;
  if (!record) return;
  const canvas = $("over-history"), ctx = canvas.getContext("2d"), palette = game.look.palette;
  const steps = record.goal.length, w = canvas.width / Math.max(1, steps);
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  ctx.fillStyle = "#fff";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  record.goal.forEach((goal, t) => {
    ctx.fillStyle = palette[goal];
    ctx.fillRect(t * w, 2, Math.ceil(w), 16);
    const said = record.stated[t];
    if (said != null) { ctx.fillStyle = palette[said]; ctx.fillRect(t * w, 22, Math.ceil(w), 16); }
  });
  for (const probe of record.probes) {
    ctx.beginPath();
    ctx.arc((probe.step + 0.5) * w, 46, 5, 0, 2 * Math.PI);
    ctx.fillStyle = palette[probe.color];
    ctx.fill();
    ctx.strokeStyle = probe.color === probe.goal ? "#000" : "#bbb";
    ctx.lineWidth = 1.5;
    ctx.stroke();
  }
  ctx.lineWidth = 1;
  canvas.setAttribute("aria-label", `the goal and the color you had said at each of ${steps} steps`);
  const pct = (v) => `${Math.round(100 * v)}%`;
  const said = record.accuracy == null ? "You did not say which color you believed was the goal."
    : `Your stated color was the goal at ${pct(record.accuracy)} of the ${record.stated_steps} steps where you had ` +
      `said one (of ${record.steps}).`;
  const asked = record.probes_asked === 0 ? "" : record.probe_accuracy == null
    ? ` You answered none of the ${record.probes_asked} questions.`
    : ` ${pct(record.probe_accuracy)} of your ${record.probes_answered} answers to the ${record.probes_asked} ` +
      "questions named the goal.";
  $("over-accuracy").textContent = said + asked;
}
