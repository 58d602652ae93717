// The participant's page of a study: it shows the page the server says the participant is on
// (consent, instructions, a game, questions, the debrief) and reports what they did. The server
// keeps the progress, so a reload continues where the participant was. See docs/STUDIES.md.
import { drawBoard, drawBelief, setLook } from "./board.js";
import { countdown } from "./countdown.js";
import { playSocket } from "./socket.js";
import { plainEnding } from "./messages.js";
import { describe, disc, drawLegend } from "./study_people.js";

const $ = (id) => document.getElementById(id);
const params = Object.fromEntries(new URLSearchParams(location.search));
let info = null, who = null, view = null, socket = null, game = null, seq = 0;

function status(text, kind = "") {
  $("status").textContent = text;
  $("status").className = kind;
}

async function api(path, body, tries = 1) {
  let response = null;
  for (let attempt = 1; ; attempt++) {  // a process stopped mid-request: the proxy's 502/503, or no answer at all
    response = await fetch(`/api/study/${path}`, {
      method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
    }).catch((err) => { if (attempt >= tries) throw err; return null; });
    if (attempt >= tries || (response && ![502, 503].includes(response.status))) break;
    await new Promise((resolve) => setTimeout(resolve, 1000 * attempt));
  }
  const data = await response.json();
  if (!response.ok) {  // a sentence; answers that cannot be taken: every problem, by question (422)
    const detail = data.detail;
    const err = new Error(typeof detail === "string" ? detail : detail?.message ?? "the request was refused");
    err.problems = detail?.problems ?? null;
    throw err;
  }
  return data;
}

function storageKey() {
  const id = info.id_params.map((name) => params[name]).find(Boolean) ?? "anonymous";
  return `colorgrid-study:${info.id}:${id}`;
}

function newSession() {
  const bytes = crypto.getRandomValues(new Uint8Array(24));
  return btoa(String.fromCharCode(...bytes)).replaceAll("+", "-").replaceAll("/", "_");  // 32 URL-safe characters
}

async function join() {
  info = await (await fetch("/api/study/info")).json();
  document.title = info.title;
  $("study-title").textContent = info.title;
  const saved = JSON.parse(localStorage.getItem(storageKey()) ?? "null");
  const sent = { ...params, ...(saved?.pid && info.anonymous ? { _pid: saved.pid } : {}) };
  // A first join proposes its own session key, kept before it is sent: the same join sent again (its answer
  // lost to a stopped process) resumes the participant instead of finding them "already started".
  const session = saved?.session ?? newSession();
  if (!saved) localStorage.setItem(storageKey(), JSON.stringify({ session }));
  const joined = await api("join", { params: sent, session }, 3);
  who = { pid: joined.pid, session: joined.session };
  localStorage.setItem(storageKey(), JSON.stringify(who));
  show(joined.view);
}

function show(next) {
  view = next;
  $("page").hidden = false;
  $("game").hidden = true;
  $("page-title").textContent = view.title || { consent: "Consent", instructions: "Instructions", practice: "Practice",
    trial: "Game", questions: "Questions", questionnaire: "Questions", debrief: "Thank you" }[view.kind];
  if (view.kind === "trial") $("page-title").textContent += ` ${view.trial_index + 1} of ${view.trials}`;
  $("page-text").innerHTML = view.html;  // rendered by the server from the study file (raw HTML is escaped)
  $("progress").textContent = `page ${view.step + 1} of ${view.steps}`;
  $("questions").replaceChildren(...(view.questions ?? []).map(questionField));
  $("legend").hidden = !["instructions", "practice", "trial"].includes(view.kind);  // who is who, before each game
  drawLegend($("legend"), view.look, view.agent);
  $("completion").hidden = view.kind !== "debrief";
  if (view.kind === "debrief") {
    $("completion-code").textContent = view.completion_code;
    $("redirect").hidden = !view.redirect_url;
    $("redirect").href = view.redirect_url || "#";
  }
  const gamePage = Boolean(view.game);
  $("play").hidden = !gamePage || Boolean(view.done);
  $("next").hidden = view.kind === "debrief" || (gamePage && !view.done);
  $("next").textContent = view.kind === "consent" ? "I agree" : "Continue";
  status(view.done ? ending(view) : view.interrupted ? INTERRUPTED : "", view.interrupted ? "warn" : "");
  if (view.live) connect({ type: "rejoin", game_id: view.live.game_id, token: view.live.token });
}

const INTERRUPTED = "Your game was interrupted: the server running it stopped. Press Play to play this game again.";

function ending(page) {
  // The game just played, in words: how it ended and the team's score (a practice game's does not count).
  const score = page.done.scores?.team;
  const points = score == null ? "" : ` Your team scored ${score > 0 ? "+" : ""}${score}`;
  if (page.kind === "practice") return `Practice over.${points ? `${points}, which does not count.` : ""}`;
  return `${plainEnding(page.done.ended)}${points ? `${points}.` : ""}`;
}

function questionField(q) {
  const box = document.createElement("fieldset");
  box.className = "question";
  box.dataset.id = q.id;
  const legend = document.createElement("legend");
  legend.textContent = q.prompt;
  if (!q.required && !/\(optional\)/i.test(q.prompt)) legend.append(span("(optional)", "optional"));
  box.append(legend);
  if (q.kind === "text") {
    const area = document.createElement("textarea");
    area.name = q.id;
    area.maxLength = q.max_length;
    area.rows = 3;
    box.append(area);
    return box;
  }
  const choices = q.kind === "likert" ? Array.from({ length: q.scale }, (_, i) => String(i + 1)) : q.options;
  if (q.kind === "likert" && q.labels.length) box.append(span(q.labels[0], "note"));
  for (const value of choices) {
    const label = document.createElement("label");
    label.className = "choice";
    const input = document.createElement("input");
    Object.assign(input, { type: "radio", name: q.id, value });
    label.append(input, " ", value);
    box.append(label);
  }
  if (q.kind === "likert" && q.labels.length) box.append(span(q.labels[1], "note"));
  return box;
}

function span(text, className) {
  const element = document.createElement("span");
  element.className = className;
  element.textContent = ` ${text} `;
  return element;
}

function answers() {
  const out = {};
  for (const q of view.questions ?? []) {
    const field = $("questions").elements.namedItem(q.id);
    const value = field?.value ?? "";
    out[q.id] = value === "" ? null : q.kind === "likert" ? Number(value) : value;
  }
  return out;
}

async function next() {
  try {
    const body = { ...who, step: view.step, agree: view.kind === "consent" };
    if (view.questions) body.answers = answers();
    showProblems([]);
    show(await api("advance", body, 3));
  } catch (err) {
    if (err.problems) {
      showProblems(err.problems);
    } else {
      status(err.message, "error");
    }
  }
}

function showProblems(problems) {
  // The server's problems with the answers, each beside its question; the status line names the questions.
  for (const box of $("questions").querySelectorAll("fieldset.question")) {
    const problem = problems.find((p) => p.question === box.dataset.id);
    box.querySelector(".problem")?.remove();
    box.removeAttribute("aria-invalid");
    if (!problem) continue;
    const note = document.createElement("p");
    note.className = "problem";
    note.id = `problem-${box.dataset.id}`;
    note.textContent = problem.problem;
    box.setAttribute("aria-invalid", "true");
    box.setAttribute("aria-describedby", note.id);
    box.append(note);
  }
  if (!problems.length) return;
  const list = document.createElement("ul");
  list.replaceChildren(...problems.map((p) => Object.assign(document.createElement("li"), { textContent: p.prompt })));
  $("status").replaceChildren(problems.length === 1 ? "Please look again at this question:"
    : `Please look again at these ${problems.length} questions:`, list);
  $("status").className = "error";
  $("questions").querySelector("fieldset[aria-invalid=true] input, fieldset[aria-invalid=true] textarea")?.focus();
}

// ------------------------------------------------------------------ games
function connect(firstMessage) {
  playSocket(firstMessage, {
    onOpen: (opened) => { socket = opened; },
    onMessage,
    liveGame: () => (game && !game.over && !game.replaced ? game : null),
    onDrop: () => status("connection lost: reconnecting...", "warn"),
  });
}

function onMessage(msg) {
  if (msg.type === "welcome") {
    game = { ...msg, over: false };
    setLook(msg.look);
    $("page").hidden = true;
    $("game").hidden = false;
    $("belief-panel").hidden = true;  // shown once the follower has a belief to show: some have none
    drawLegend($("game-legend"), msg.look, view.agent);
    firstGameNote(msg.look);
    $("score-label").textContent = view.kind === "practice" ? "practice score (does not count)" : "team score";
    if (!$("countdown").hidden) setTimeout(() => { $("countdown").hidden = true; }, 700);
    status("");
    $("board").focus();
  } else if (msg.type === "state") {
    render(msg);
  } else if (msg.type === "game_over") {
    game.over = true;
    api("view", who).then(show).catch((err) => status(err.message, "error"));
  } else if (msg.type === "error" || msg.type === "full") {
    console.info(msg);
    $("countdown").hidden = true;
    if (game && !game.over && msg.code === "rejected") {  // its server stopped: the game cannot be rejoined
      game = null;
      socket?.close();
      api("view", who).then(show).catch((err) => status(err.message, "error"));  // it offers to play it again
      return;
    }
    if (!game) {  // the game was not made: show the page again (its button starts it)
      api("view", who).then(show).catch((err) => status(err.message, "error"));
    }
    status(msg.type === "full" ? "the server is busy: try again in a minute" : "something went wrong: try again", "error");
  } else if (msg.type === "replaced") {
    game.replaced = true;
    status("this game continues in another tab or window", "warn");
  }
}

function render(state) {
  drawBoard($("board"), { height: game.height, width: game.width, ...state });
  $("board").dataset.step = state.step;
  $("step").textContent = `${state.step} / ${state.horizon}`;
  $("score-team").textContent = (state.scores.team > 0 ? "+" : "") + state.scores.team;
  $("goal-swatch").style.background = game.look.palette[state.goal];
  $("goal-name").textContent = game.colors[state.goal];
  $("board").setAttribute("aria-label", describe({ height: game.height, width: game.width, ...state }, game.look,
                                                 view.agent, game.colors));
  if (game.show_belief && state.belief) {
    $("belief-panel").hidden = false;
    drawBelief($("belief"), state.belief, game.colors);
  }
}

function firstGameNote(lookValue) {
  // On the practice game and the first trial: which disc is the participant's, in a sentence.
  const first = view.kind === "practice" || (view.kind === "trial" && view.trial_index === 0);
  $("first-game-note").hidden = !first;
  if (!first) return;
  const you = lookValue.agents.find((a) => a.name === view.agent);
  const partners = lookValue.agents.filter((a) => a.name !== view.agent);
  $("first-game-note").replaceChildren("You are ", disc(you), ". Your AI partner is ",
                                       ...partners.flatMap((a, i) => (i ? [" and ", disc(a)] : [disc(a)])), ".");
}

async function play() {
  seq = 0;
  game = null;
  $("play").hidden = true;
  if (view.game.mode === "realtime") {  // nothing moves, and no key counts, until "go"
    $("page").hidden = true;
    await countdown($("countdown"));
    $("countdown").textContent = "go";
  }
  const viewport = [window.innerWidth, window.innerHeight];
  connect({ type: "new_game", study: { participant: who.pid, session: who.session }, viewport });
}

function pageEvent(event) {
  if (!game || game.over || !socket || socket.readyState !== WebSocket.OPEN) return;
  socket.send(JSON.stringify({ type: "page_event", event, visible: document.visibilityState === "visible",
                               t_client: performance.timeOrigin + performance.now() }));
}

document.addEventListener("keydown", (event) => {
  if (!game || game.over || !socket || socket.readyState !== WebSocket.OPEN || !game.keys.includes(event.key)) return;
  event.preventDefault();
  socket.send(JSON.stringify({ type: "key", key: event.key, seq: seq++, t_client: performance.timeOrigin + performance.now() }));
});
window.addEventListener("blur", () => pageEvent("blur"));
window.addEventListener("focus", () => pageEvent("focus"));
document.addEventListener("visibilitychange", () => pageEvent("visibilitychange"));
$("next").addEventListener("click", next);
$("play").addEventListener("click", play);
$("questions").addEventListener("submit", (event) => event.preventDefault());

join().catch((err) => {
  $("page").hidden = false;
  $("page-title").textContent = "This study cannot continue here";
  $("page-text").textContent = err.message;
  $("next").hidden = $("play").hidden = true;
});
