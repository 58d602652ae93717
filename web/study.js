// The participant's page of a study: it shows the page the server says the participant is on
// (consent, instructions, a game, questions, the debrief) and reports what they did. The server
// keeps the progress, so a reload continues where the participant was. See docs/STUDIES.md.
import { setLook } from "./board.js";
import { countdown } from "./countdown.js";
import { PlaySocket } from "./socket.js";
import { OwnMove } from "./predict.js";
import { plainEnding, plainError, setEndings } from "./messages.js";
import { describe, disc, drawLegend } from "./study_people.js";
import { drawState, gameName, startGame } from "./study_game.js";
import { answerProbe, drawStated, probeRefused, seatKey, showProbeConfidence, startSeat } from "./follower_seat.js";
import { PlayPings, measureScreen } from "./study_screen.js";
import { MODE, ROLE } from "./sets.js";

const $ = (id) => document.getElementById(id);
const params = Object.fromEntries(new URLSearchParams(location.search));
let info = null, who = null, view = null, game = null, seq = 0, own = null, lastState = null;

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
    err.detail = detail;  // a participant who finished: their completion code comes with the refusal
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
  const [studyInfo, options] = await Promise.all([fetch("/api/study/info"), fetch("/api/options")]);
  info = await studyInfo.json();
  setEndings((await options.json()).endings);  // how a game ended, in the server's words
  document.title = info.title;
  $("study-title").textContent = info.title;
  const saved = JSON.parse(localStorage.getItem(storageKey()) ?? "null");
  const sent = { ...params, ...(saved?.pid && info.anonymous ? { _pid: saved.pid } : {}) };
  // A first join proposes its own session key, kept before it is sent: the same join sent again (its answer
  // lost to a stopped process) resumes the participant instead of finding them "already started".
  const session = saved?.session ?? newSession();
  if (!saved) localStorage.setItem(storageKey(), JSON.stringify({ session }));
  const screen = info.screening ? await measureScreen(info.screening.pings) : null;  // the study's [screening]
  const joined = await api("join", { params: sent, session, ...(screen ? { screen } : {}) }, 3);
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
  $("check-note").hidden = true;
  $("legend").hidden = !["instructions", "practice", "trial"].includes(view.kind);  // who is who, before each game
  drawLegend($("legend"), view.look, view.agent);
  // the board, its frame and its discs, labelled (for the leader's seat: the picture says "you are L")
  $("board-picture").hidden = view.kind !== "instructions" || assisting(view);
  $("completion").hidden = view.kind !== "debrief";
  if (view.kind === "debrief") showCompletion(view.completion_code, view.redirect_url);
  const gamePage = Boolean(view.game);
  $("page-text").hidden = gamePage && Boolean(view.done);  // "Play with your AI partner" is for before the game
  showEnd(view);
  $("play").hidden = !gamePage || Boolean(view.done);
  $("next").hidden = view.kind === "debrief" || (gamePage && !view.done);
  $("next").textContent = view.kind === "consent" ? "I agree" : "Continue";
  status(view.interrupted ? interrupted() : "", view.interrupted ? "warn" : "");
  if (view.live) connect({ type: "rejoin", game_id: view.live.game_id, token: view.live.token });
}

function interrupted() {
  // The button's own words: the participant is told to press what they see.
  return `Your game was interrupted: the server running it stopped. Press "${$("play").textContent}" to play ` +
    "this game again.";
}

function showEnd(page) {
  // The game just played, in a panel of its own: which game, the team's score (a practice game's does not count)
  // and, when it did not simply run to its end, how it ended.
  $("game-end").hidden = !page.done;
  if (!page.done) return;
  const practice = page.kind === "practice";
  $("game-end-title").textContent = practice ? "The practice game is over" : `${gameName(page)} is over`;
  const score = page.done.scores?.team;
  $("game-end-score").textContent = score == null ? ""
    : `Your team scored ${score > 0 ? "+" : ""}${score}${practice ? " (practice: it does not count)" : ""}`;
  const how = page.done.ended === "complete" ? "" : `${plainEnding(page.done.ended)} `;
  $("game-end-note").textContent = `${how}Press Continue when you are ready.`;
}

function showCompletion(code, url) {
  // The completion code and the way back to the study platform (the debrief; a finished participant's refusal).
  $("completion").hidden = !code && !url;
  $("completion-code").textContent = code;
  $("redirect").hidden = !url;
  $("redirect").href = url || "#";
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
  const choices = q.kind === "likert" ? Array.from({ length: q.scale }, (_, i) => String(i + 1)) : q.options;  // check: a choice
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
    showProblems([], false);
    show(await api("advance", body, 3));
  } catch (err) {
    if (err.detail?.again) {  // a check answered wrong: the page (its instructions) again, from the top
      readAgain(err.problems);
    } else if (err.problems) {
      showProblems(err.problems);
    } else {
      status(err.message, "error");
    }
  }
}

let problemsShown = [];

function readAgain(problems) {
  // A wrong answer to a check: the note above the page's text, the wrong answers cleared, the page from its top.
  for (const p of problems) {
    for (const input of $("questions").querySelectorAll(`fieldset[data-id="${p.question}"] input`)) input.checked = false;
  }
  showProblems(problems, false);
  $("check-note").textContent = view.kind === "instructions"
    ? "Not quite: please read the instructions again, then answer the question below once more."
    : "Not quite: please read the question again and answer once more.";
  $("check-note").hidden = false;
  $("page").scrollIntoView({ block: "start" });
  $("page-title").focus();
}

function showProblems(problems, focus = true) {
  // The server's problems with the answers, each beside its question; the status line names the questions.
  problemsShown = problems;
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
  if (!problems.length) {
    if ($("status").className === "error" && $("status").querySelector("ul")) status("");
    return;
  }
  const list = document.createElement("ul");
  list.replaceChildren(...problems.map((p) => Object.assign(document.createElement("li"), { textContent: p.prompt })));
  $("status").replaceChildren(problems.length === 1 ? "Please look again at this question:"
    : `Please look again at these ${problems.length} questions:`, list);
  $("status").className = "error";
  const first = $("questions").querySelector("fieldset[aria-invalid=true] input, fieldset[aria-invalid=true] textarea");
  if (focus) first?.focus();
}

function answered(event) {
  // A question answered after its problem was shown: the problem goes at once (Continue still asks the server).
  const id = event.target.closest("fieldset.question")?.dataset.id;
  if (problemsShown.some((p) => p.question === id)) showProblems(problemsShown.filter((p) => p.question !== id), false);
}

// ------------------------------------------------------------------ games
// One connection, for the game in play (web/socket.js): only its messages count, it rejoins the game after a drop,
// and it is closed when the game ends.
const pings = new PlayPings((message) => connection.ready && connection.send(message));  // round trips in play
const connection = new PlaySocket({
  onMessage,
  resume: () => (game && !game.over && !game.replaced ? { type: "rejoin", game_id: game.game_id, token: game.token }
    : null),
  onDrop: () => status("connection lost: reconnecting...", "warn"),
  onUnanswered: () => {  // the game asked for may or may not have been made: the server's view of the page says
    $("countdown").hidden = true;
    api("view", who, 3).then((page) => {
      show(page);
      if (!page.live && !page.interrupted && !page.done) status(joinLost(), "warn");
    }).catch((err) => status(err.message, "error"));
  },
});

function connect(firstMessage) {
  connection.start(firstMessage);
}

function joinLost() {
  return `The connection was lost while your game was starting. Press "${$("play").textContent}" to start it.`;
}

function onMessage(msg) {
  if (msg.type === "welcome") {
    game = { ...msg, over: false };
    seq = msg.next_seq;  // keys number on across reloads and reconnects
    own = new OwnMove(msg, view.agent);  // the participant's own moves, drawn before the server's state shows them
    lastState = null;
    setLook(msg.look);
    $("page").hidden = true;
    $("game").hidden = false;
    startGame(game, view);  // the board's size, which game, the belief panel: fixed from the first step
    startSeat(game, (message) => connection.send(message),  // the follower seat: say what you believe, probes
              (hint) => { $("how-to-move").textContent = `Move with the arrow keys or W, A, S, D. ${hint}`; });
    $("how-to-move").textContent = msg.seat !== ROLE.FOLLOWER ? "Move with the arrow keys or W, A, S, D. The frame " +
      "around the board is the goal color." : `Move with the arrow keys or W, A, S, D. Say which color you believe ` +
      `is the goal with ${Object.keys(msg.belief_keys).join(", ")} or a click on a color.`;
    drawLegend($("game-legend"), msg.look, view.agent);
    firstGameNote(msg.look);
    $("score-label").textContent = view.kind === "practice" ? "practice score (does not count)" : "team score";
    if (!$("countdown").hidden) setTimeout(() => { $("countdown").hidden = true; }, 700);
    status("");
    $("board").focus();
    pings.start();
  } else if (msg.type === "pong") {
    pings.pong();
  } else if (msg.type === "state") {
    lastState = msg;
    render(own.shown(msg));
  } else if (msg.type === "game_over") {
    game.over = true;
    pings.stop();
    connection.close();  // one connection a game (the server closes it too)
    api("view", who).then(show).catch((err) => status(err.message, "error"));
  } else if (msg.type === "error" || msg.type === "full") {
    console.info(msg);
    $("countdown").hidden = true;
    if (game && !game.over && msg.code === "bad_probe") {  // the probe asks again, with the reason
      probeRefused(game, plainError(msg));
      return;
    }
    if (game && !game.over && msg.code === "rejected") {  // its server stopped: the game cannot be rejoined
      game = null;
      pings.stop();
      connection.close();
      api("view", who).then(show).catch((err) => status(err.message, "error"));  // it offers to play it again
      return;
    }
    if (!game) {  // the game was not made: show the page again (its button starts it)
      connection.close();
      api("view", who).then(show).catch((err) => status(err.message, "error"));
    }
    status(msg.type === "full" ? "the server is busy: try again in a minute" : plainError(msg), "error");
  } else if (msg.type === "replaced") {
    game.replaced = true;
    pings.stop();
    connection.close();
    status("this game continues in another tab or window", "warn");
  }
}

function render(state) {
  drawState(game, state);
  drawStated(game, state);
  $("board").dataset.step = state.step;
  $("board").dataset.you = state[view.agent];  // where the participant's disc is drawn (predicted: web/predict.js)
  $("board").dataset.goal = state.goal;
  $("step").textContent = `${state.step} / ${state.horizon}`;
  $("score-team").textContent = (state.scores.team > 0 ? "+" : "") + state.scores.team;
  $("goal-swatch").style.background = state.goal == null ? "#999" : game.look.palette[state.goal];
  $("goal-name").textContent = state.goal == null ? "hidden from you" : game.colors[state.goal];
  $("board").setAttribute("aria-label", describe({ height: game.height, width: game.width, ...state }, game.look,
                                                 view.agent, game.colors));
}

function firstGameNote(lookValue) {
  // On the practice game and the first trial: which disc is the participant's, in a sentence.
  const first = view.kind === "practice" || (view.kind === "trial" && view.trial_index === 0);
  $("first-game-note").hidden = !first;
  if (!first) return;
  const you = lookValue.agents.find((a) => a.name === view.agent);
  const partners = lookValue.agents.filter((a) => a.name !== view.agent);
  if (assisting(view)) {
    $("first-game-note").replaceChildren("You are ", disc(you), ". The AI leader is ", ...partners.map(disc),
                                         ": it knows the goal.");
    return;
  }
  $("first-game-note").replaceChildren("You are ", disc(you), ". Your AI partner is ",
                                       ...partners.flatMap((a, i) => (i ? [" and ", disc(a)] : [disc(a)])), ".");
}

async function play() {
  seq = 0;
  game = null;
  $("play").hidden = true;
  if (view.game.mode === MODE.REALTIME) {  // nothing moves, and no key counts, until "go"
    $("page").hidden = true;
    await countdown($("countdown"));
    $("countdown").textContent = "go";
  }
  const viewport = [window.innerWidth, window.innerHeight];
  connect({ type: "new_game", study: { participant: who.pid, session: who.session }, viewport });
}

function pageEvent(event) {
  if (!game || game.over) return;
  connection.send({ type: "page_event", event, visible: document.visibilityState === "visible",
                    t_client: performance.timeOrigin + performance.now() });
}

function assisting(page) {
  // whether the participant plays the follower (beside an AI leader) on this page
  return page.look?.agents.find((a) => a.name === page.agent)?.role === ROLE.FOLLOWER;
}

function sendKey(key) {
  return connection.send({ type: "key", key, seq: seq++, t_client: performance.timeOrigin + performance.now() });
}

document.addEventListener("keydown", (event) => {
  if (game && !game.over && connection.ready && seatKey(game, event, sendKey, (m) => connection.send(m))) {
    event.preventDefault();  // the follower seat's own keys: a belief, or the probe's answer
    return;
  }
  if (!game || game.over || !connection.ready || !game.keys.includes(event.key)) return;
  event.preventDefault();
  connection.send({ type: "key", key: event.key, seq, t_client: performance.timeOrigin + performance.now() });
  own.press(event.key, seq++);
  if (lastState) render(own.shown(lastState));  // the participant's own move at once; the server's state corrects it
});
window.addEventListener("blur", () => pageEvent("blur"));
window.addEventListener("focus", () => pageEvent("focus"));
document.addEventListener("visibilitychange", () => pageEvent("visibilitychange"));
$("next").addEventListener("click", next);
$("probe-confidence").addEventListener("input", showProbeConfidence);
$("probe-answer").addEventListener("click", () => answerProbe(game, (message) => connection.send(message)));
$("play").addEventListener("click", play);
$("questions").addEventListener("submit", (event) => event.preventDefault());
$("questions").addEventListener("input", answered);

join().catch((err) => {
  $("page").hidden = false;
  const finished = err.detail?.completion_code !== undefined;  // finished before, in another browser
  const screened = err.detail?.return_code !== undefined;  // the study's [screening] refused this device
  $("page-title").textContent = finished ? "You have completed this study" : "This study cannot continue here";
  $("page-text").textContent = err.message;
  if (finished) showCompletion(err.detail.completion_code, err.detail.redirect_url);
  if (screened) {
    $("code-label").textContent = "Your return code:";
    showCompletion(err.detail.return_code, err.detail.redirect_url);
  }
  $("next").hidden = $("play").hidden = true;
});
