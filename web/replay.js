// The replay player: /replay?id=ID&step=N. Board (same drawing as the play page), transport controls,
// the episode chart with a synced cursor, trails, the key log of human games, downloads and step links, and
// "branch here" (branch.js: the replay continued with another follower, drawn beside it at the same step).
// Colors and agents come with the timeline (`data.look`, agents in index order: the leader first).
import { drawBoard, drawBelief, setLook } from "./board.js";
import { setupBranch, showBranch } from "./branch.js";
import { drawChart, stepAt } from "./chart.js";
import { queryParam } from "./params.js";

const $ = (id) => document.getElementById(id);
const id = queryParam("id");
const TRAIL = 12;
const BASE_FPS = 8;  // steps per second at 1x
let data = null, step = 0, timer = null;

function setStatus(text, kind = "") { $("status").textContent = text; $("status").className = kind; }

async function main() {
  if (!id) { setStatus("no replay chosen: open one from the replay list", "error"); return; }
  const response = await fetch(`/api/replays/${encodeURIComponent(id)}/timeline`);
  if (!response.ok) { setStatus(`replay ${id}: ${(await response.json()).detail || response.statusText}`, "error"); return; }
  data = await response.json();
  document.body.dataset.verified = data.verified;
  if (!data.verified) {
    setStatus(`This replay failed verification and is not played: ${data.problem}`, "error");
    return;
  }
  setStatus("");
  setLook(data.look);
  $("player").hidden = false;
  $("title").textContent = id;
  for (const agent of data.look.agents) $(`${agent.name}-label`).textContent = data.agents[agent.name]?.policy ?? "?";
  const enc = encodeURIComponent(id);
  $("gif").href = `/api/replays/${enc}/export?format=gif`;
  $("mp4").href = `/api/replays/${enc}/export?format=mp4`;
  $("json").href = `/api/replays/${enc}`;
  $("gif").download = `${id}.gif`;
  $("mp4").download = `${id}.mp4`;
  $("facts").textContent = `${data.source} replay, ${data.steps} steps, ${data.ended}` +
    (data.seed != null ? `, seed ${data.seed}` : "") + `, created ${data.created}`;
  $("scrub").max = data.steps;
  buildKeyLog();
  const wanted = Number.parseInt(queryParam("step") ?? "0", 10);
  show(Number.isFinite(wanted) ? wanted : 0);
  await setupBranch(id, data, () => step);
}

function show(t) {
  step = Math.max(0, Math.min(data.steps, t));
  const board = data.boards[step];
  const canvas = $("board");
  const cell = drawBoard(canvas, { height: data.height, width: data.width, ...board });
  if ($("trails").checked) drawTrails(canvas, cell);
  canvas.dataset.step = step;
  for (const agent of data.look.agents) canvas.dataset[agent.name] = board[agent.name];
  $("scrub").value = step;
  $("step").textContent = `${step} / ${data.steps}`;
  $("goal-name").textContent = data.colors[board.goal];
  $("goal-swatch").style.background = data.look.palette[board.goal];
  if (board.scores) {
    $("score-team").textContent = board.scores.reduce((a, b) => a + b, 0).toFixed(0);
    data.look.agents.forEach((agent, i) => { $(`score-${agent.name}`).textContent = board.scores[i].toFixed(0); });
  }
  const [, follower] = data.look.agents;  // the bars show the follower's beliefs
  const probs = data.goal_probs?.[follower.name];
  drawBelief($("belief"), probs ? probs[Math.min(step, data.steps - 1)] : null, data.colors);
  drawChart($("chart"), data, step);
  showBranch(step);
  const link = new URL(location.href);
  link.searchParams.set("step", step);
  $("step-link").href = link.pathname + link.search;
  history.replaceState(null, "", link.pathname + link.search);
  for (const tr of $("keylog").tBodies[0].rows) tr.classList.toggle("highlight", Number(tr.dataset.step) === step);
}

function drawTrails(canvas, cell) {
  const ctx = canvas.getContext("2d");
  const border = 4;
  for (const agent of data.look.agents) {  // dots in the agent's body color, ringed in its ink
    for (let k = Math.max(0, step - TRAIL); k < step; k++) {
      const idx = data.boards[k][agent.name];
      const r = Math.floor(idx / data.width), c = idx % data.width;
      ctx.globalAlpha = 0.15 + (0.6 * (k - step + TRAIL)) / TRAIL;
      ctx.fillStyle = agent.body;
      ctx.strokeStyle = agent.ink;
      ctx.beginPath();
      ctx.arc(border + c * cell + cell / 2, border + r * cell + cell / 2, cell / 5, 0, 2 * Math.PI);
      ctx.fill();
      ctx.stroke();
    }
  }
  ctx.globalAlpha = 1;
}

function buildKeyLog() {
  const keys = data.key_events || [];
  $("keylog-panel").hidden = keys.length === 0;
  let previous = null;
  $("keylog").tBodies[0].replaceChildren(...keys.map((k) => {
    const tr = document.createElement("tr");
    tr.dataset.step = k.applied_step ?? "";
    const gap = previous == null ? "" : (k.t_client - previous).toFixed(0);
    previous = k.t_client;
    for (const v of [k.seq, k.key, k.applied_step ?? "-", k.status, k.reaction_ms ?? "", gap]) {
      const td = document.createElement("td"); td.textContent = v; tr.appendChild(td);
    }
    tr.addEventListener("click", () => k.applied_step != null && show(k.applied_step));
    return tr;
  }));
}

function speed() { return Number($("speed").value); }
function play() {
  if (timer) return;
  if (step >= data.steps) show(0);
  $("play").textContent = "pause";
  timer = setInterval(() => { if (step >= data.steps) pause(); else show(step + 1); }, 1000 / (BASE_FPS * speed()));
}
function pause() { clearInterval(timer); timer = null; $("play").textContent = "play"; }
function restartIfPlaying() { if (timer) { pause(); play(); } }
function nudgeSpeed(dir) {
  const s = $("speed");
  s.selectedIndex = Math.max(0, Math.min(s.options.length - 1, s.selectedIndex + dir));
  restartIfPlaying();
}

$("play").addEventListener("click", () => (timer ? pause() : play()));
$("back").addEventListener("click", () => { pause(); show(step - 1); });
$("forward").addEventListener("click", () => { pause(); show(step + 1); });
$("first").addEventListener("click", () => { pause(); show(0); });
$("last").addEventListener("click", () => { pause(); show(data.steps); });
$("scrub").addEventListener("input", (e) => { pause(); show(Number(e.target.value)); });
$("speed").addEventListener("change", restartIfPlaying);
$("trails").addEventListener("change", () => show(step));
$("chart").addEventListener("click", (e) => {
  const rect = e.target.getBoundingClientRect();
  pause();
  show(stepAt(e.target, data, ((e.clientX - rect.left) * e.target.width) / rect.width));
});
document.addEventListener("keydown", (e) => {
  if (!data?.verified || e.target.tagName === "INPUT" && e.target.type !== "range" && e.target.type !== "checkbox") return;
  const actions = {
    " ": () => (timer ? pause() : play()), ArrowLeft: () => { pause(); show(step - 1); },
    ArrowRight: () => { pause(); show(step + 1); }, Home: () => { pause(); show(0); },
    End: () => { pause(); show(data.steps); }, "+": () => nudgeSpeed(1), "=": () => nudgeSpeed(1),
    "-": () => nudgeSpeed(-1), t: () => { $("trails").checked = !$("trails").checked; show(step); },
  };
  if (actions[e.key]) { e.preventDefault(); actions[e.key](); }
});
main();
