// The replay player: /replay?id=ID&step=N. Board (same drawing as the play page), transport controls,
// the episode chart with a synced cursor, trails, the key log of human games, downloads and step links, and
// "branch here" (branch.js: the replay continued with another follower, drawn beside it at the same step).
// Colors and agents come with the timeline (`data.look`, agents in index order: the leaders first). Every
// agent is drawn with its label and listed with its score; each follower that logged beliefs gets belief
// bars and, in teams other than 1:1, its own episode chart (1:1: the one chart, as ever). A person in a follower seat:
// their statements and probe answers on the chart, beside the AI follower of the menu (person.js).
import { agentBadge, describeBoard, drawBoard, drawBelief, setLook } from "./board.js";
import { setupBranch, showBranch } from "./branch.js";
import { drawChart, followerNames, stepAt } from "./chart.js";
import { queryParam } from "./params.js";
import { setupPerson } from "./person.js";
import { ROLE } from "./sets.js";

const $ = (id) => document.getElementById(id);
const id = queryParam("id");
const TRAIL = 12;
const BASE_FPS = 8;  // steps per second at 1x
const TEAM_NOTE = "Lines: one chart per follower that logged beliefs, its goal probabilities (dashed: a leader's). " +
  "Strip below: the true goal. Ticks: pickups (above: the leaders', below: the chart's follower's; a cross is a " +
  "wrong color). Dashes: goal switches. Click to jump. Keys: space play/pause, \u2190/\u2192 step, Home/End, " +
  "+/\u2212 speed, t trails.";
let data = null, step = 0, timer = null;
let oneToOne = true;  // one leader and one follower: the page as it always was
let beliefViews = [];  // {name, bars}: where each follower with beliefs shows them
let charts = [];  // {canvas, followers}: the episode charts and whose lines and pickups each shows
let watched = {};  // {agent: [T][C]}: the AI follower of the menu watching a person's seat (person.js)

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
  oneToOne = count("leader") === 1 && count("follower") === 1;
  buildAgentRows();
  buildBeliefs();
  buildCharts();
  const enc = encodeURIComponent(id);
  $("gif").href = `/api/replays/${enc}/export?format=gif`;
  $("mp4").href = `/api/replays/${enc}/export?format=mp4`;
  $("json").href = `/api/replays/${enc}`;
  $("gif").download = `${id}.gif`;
  $("mp4").download = `${id}.mp4`;
  const shape = oneToOne ? "" : `${count("leader")} leader(s) and ${count("follower")} follower(s), `;
  const origin = data.meta?.branch_of;  // a branch: where it leaves its parent (docs/REPLAY_FORMAT.md)
  $("facts").textContent = `${shape}${origin ? "branch" : data.source} replay, ${data.steps} steps, ${data.ended}` +
    (data.seed != null ? `, seed ${data.seed}` : "") + `, created ${data.created}`;
  if (origin) {
    const parent = document.createElement("a");
    parent.id = "parent-link";
    parent.href = `/replay?id=${encodeURIComponent(origin.file)}&step=${origin.step}`;
    parent.textContent = origin.file;
    const made = data.meta.branch ?? {};
    $("facts").append("; a branch of ", parent, ` from step ${origin.step}: ${made.follower ?? "another follower"} ` +
      `plays on${(made.leader ?? "recorded") === "recorded" ? " beside the leader's recorded moves" : ""}`);
  }
  $("scrub").max = data.steps;
  buildKeyLog();
  const wanted = Number.parseInt(queryParam("step") ?? "0", 10);
  show(Number.isFinite(wanted) ? wanted : 0);
  if (oneToOne) await setupBranch(id, data, () => step);
  else $("branch-controls").hidden = true;  // a branch continues the follower of a 1:1 team
  await setupPerson(id, data, (beliefs) => { watched = beliefs; show(step); });
}

function count(role) { return data.look.agents.filter((agent) => agent.role === role).length; }

function agentLabel(agent) { return `${agent.symbol} (${agent.name})`; }

function buildAgentRows() {
  // One row per agent: (its label on its role's colors, in teams), name, policy, score.
  $("agent-scores").replaceChildren(...data.look.agents.map((agent) => {
    const row = document.createElement("div");
    row.className = "row";
    row.dataset.agent = agent.name;
    const who = document.createElement("span");
    if (!oneToOne) who.append(agentBadge(agent), " ");
    const policy = document.createElement("span");
    policy.id = `${agent.name}-label`;
    policy.textContent = data.agents[agent.name]?.policy ?? "?";
    who.append(`${agent.name} (`, policy, ")");
    const score = document.createElement("span");
    score.id = `score-${agent.name}`;
    row.append(who, score);
    return row;
  }));
}

function buildBeliefs() {
  // 1:1: the follower's bars straight in #belief; other teams: one labelled group per follower with beliefs.
  const believers = data.look.agents.filter((agent) => agent.role === ROLE.FOLLOWER && data.goal_probs?.[agent.name]);
  if (oneToOne) { beliefViews = believers.map((agent) => ({ name: agent.name, bars: $("belief") })); return; }
  beliefViews = believers.map((agent) => {
    const group = document.createElement("section");
    group.className = "belief-group";
    group.dataset.agent = agent.name;
    const title = document.createElement("h3");
    title.textContent = `${agentLabel(agent)} believes`;
    const bars = document.createElement("div");
    group.append(title, bars);
    return { name: agent.name, bars, group };
  });
  $("belief").replaceChildren(...beliefViews.map((view) => view.group));
}

function buildCharts() {
  // 1:1, or no follower with beliefs: the one chart; other teams: one chart per follower with beliefs.
  const first = $("chart");
  if (!oneToOne) $("chart-note").textContent = TEAM_NOTE;
  if (oneToOne || beliefViews.length === 0) charts = [{ canvas: first, followers: followerNames(data) }];
  else {
    charts = beliefViews.map(({ name }, j) => {
      const canvas = j === 0 ? first : document.createElement("canvas");
      canvas.width = first.width;
      canvas.height = first.height;
      canvas.className = first.className;
      canvas.dataset.agent = name;
      const agent = data.look.agents.find((a) => a.name === name);
      canvas.setAttribute("aria-label", `${agentLabel(agent)}: goal probabilities over the episode`);
      return { canvas, followers: [name], title: `${agentLabel(agent)}: goal probabilities` };
    });
    $("charts").replaceChildren(...charts.flatMap(({ canvas, title }) => {
      const caption = document.createElement("p");
      caption.className = "chart-title";
      caption.textContent = title;
      return [caption, canvas];
    }));
  }
  for (const { canvas } of charts) canvas.addEventListener("click", jumpTo);
}

function jumpTo(e) {
  const rect = e.target.getBoundingClientRect();
  pause();
  show(stepAt(e.target, data, ((e.clientX - rect.left) * e.target.width) / rect.width));
}

function show(t) {
  step = Math.max(0, Math.min(data.steps, t));
  const board = data.boards[step];
  const canvas = $("board");
  const cell = drawBoard(canvas, { height: data.height, width: data.width, ...board });
  if ($("trails").checked) drawTrails(canvas, cell);
  canvas.dataset.step = step;
  for (const agent of data.look.agents) canvas.dataset[agent.name] = board[agent.name];
  canvas.setAttribute("aria-label", `step ${step} of ${data.steps}: ` +
    describeBoard({ height: data.height, width: data.width, ...board }, data.colors));
  $("scrub").value = step;
  $("step").textContent = `${step} / ${data.steps}`;
  $("goal-name").textContent = data.colors[board.goal];
  $("goal-swatch").style.background = data.look.palette[board.goal];
  if (board.scores) {
    $("score-team").textContent = board.scores.reduce((a, b) => a + b, 0).toFixed(0);
    data.look.agents.forEach((agent, i) => { $(`score-${agent.name}`).textContent = board.scores[i].toFixed(0); });
  }
  const acted = Math.min(step, data.steps - 1);  // beliefs are logged per action: the last step has none of its own
  for (const { name, bars } of beliefViews) drawBelief(bars, data.goal_probs[name][acted], data.colors);
  for (const { canvas, followers } of charts) drawChart(canvas, data, step, followers, watched);
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
