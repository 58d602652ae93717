// "Branch here" in the replay player: the server continues the replay from the current step with another
// follower (POST /api/replays/{id}/branch; open-loop: the leader replays its recorded moves) and the branch is
// drawn beside the original at the player's step: its board, belief bars and chart, and the team score
// difference. `setupBranch(parentId, parentData, currentStep)` once; `showBranch(step)` on every step shown.
import { drawBoard, drawBelief } from "./board.js";
import { drawChart } from "./chart.js";
import { queryParam } from "./params.js";

const $ = (id) => document.getElementById(id);
let parent = null, branch = null, opening = 0, currentStep = () => 0;

function setStatus(text, kind = "") { $("branch-status").textContent = text; $("branch-status").className = `note ${kind}`; }

function teamScore(board) { return (board.scores || []).reduce((a, b) => a + b, 0); }

function signed(x) { const v = Number(x.toFixed(2)); return (v > 0 ? "+" : v < 0 ? "\u2212" : "\u00b1") + Math.abs(v); }

async function detail(response) {
  try { return (await response.json()).detail ?? response.statusText; } catch { return response.statusText; }
}

export async function setupBranch(parentId, parentData, stepShown) {
  parent = parentData;
  currentStep = stepShown;
  const response = await fetch("/api/options");
  if (!response.ok) { setStatus(`cannot branch: ${await detail(response)}`, "error"); return; }
  const options = await response.json();
  $("branch-follower").replaceChildren(...options.followers.map((name) => new Option(name, name)));
  $("branch-follower").value = options.default_follower;
  $("branch-here").addEventListener("click", () => makeBranch(parentId));
  $("branch-close").addEventListener("click", closeBranch);
  const wanted = queryParam("branch");
  if (wanted) await openBranch(wanted);
}

async function makeBranch(parentId) {
  const step = currentStep(), follower = $("branch-follower").value;
  $("branch-here").disabled = true;
  setStatus(`branching at step ${step} with ${follower}\u2026`);
  try {
    const response = await fetch(`/api/replays/${encodeURIComponent(parentId)}/branch`, {
      method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify({ step, follower }),
    });
    if (!response.ok) { setStatus(`cannot branch: ${await detail(response)}`, "error"); return; }
    await openBranch((await response.json()).id);
  } catch (err) {
    setStatus(`cannot branch: ${err.message}`, "error");
  } finally {
    $("branch-here").disabled = false;
  }
}

async function openBranch(branchId) {
  const mine = ++opening;  // a later branch wins over one still loading
  setStatus("loading the branch\u2026");
  const response = await fetch(`/api/replays/${encodeURIComponent(branchId)}/timeline`);
  const data = response.ok ? await response.json() : null;
  if (mine !== opening) return;
  if (!data) { setStatus(`branch ${branchId}: ${await detail(response)}`, "error"); return; }
  if (!data.verified) { setStatus(`the branch failed verification: ${data.problem}`, "error"); return; }
  branch = data;
  const info = data.meta?.branch ?? {};
  $("branch-title").textContent = `branch: ${info.follower ?? data.agents.follower?.policy ?? "?"} from step ${info.step ?? "?"}`;
  $("branch-panel").hidden = false;
  $("branch-panel").dataset.id = branchId;
  setStatus("");
  setUrl(branchId);
  showBranch(currentStep());
}

function closeBranch() {
  opening++;
  branch = null;
  $("branch-panel").hidden = true;
  delete $("branch-panel").dataset.id;
  setUrl(null);
}

function setUrl(branchId) {
  const params = location.search.replace(/^\?/, "").split("&").filter((p) => p && !p.startsWith("branch="));
  if (branchId) params.push(`branch=${encodeURIComponent(branchId)}`);
  history.replaceState(null, "", `${location.pathname}?${params.join("&")}`);
}

export function showBranch(step) {
  if (!branch) return;
  const t = Math.max(0, Math.min(branch.steps, step));  // a branch has the original's steps or fewer
  const board = branch.boards[t];
  const canvas = $("branch-board");
  drawBoard(canvas, { height: branch.height, width: branch.width, ...board });
  canvas.dataset.step = t;
  for (const agent of branch.look.agents) canvas.dataset[agent.name] = board[agent.name];
  $("branch-step").textContent = `${t} / ${branch.steps}`;
  $("branch-score-team").textContent = teamScore(board).toFixed(0);
  const original = parent.boards[Math.max(0, Math.min(parent.steps, step))];
  const now = teamScore(board) - teamScore(original);
  const end = teamScore(branch.boards[branch.steps]) - teamScore(parent.boards[parent.steps]);
  const diff = $("branch-diff");
  diff.textContent = `team score, branch \u2212 original: ${signed(now)} at step ${t}, ${signed(end)} at the end`;
  diff.dataset.now = now;
  diff.dataset.end = end;
  const [, follower] = branch.look.agents;
  const probs = branch.goal_probs?.[follower.name];
  drawBelief($("branch-belief"), probs?.length ? probs[Math.min(t, branch.steps - 1)] : null, branch.colors);
  drawChart($("branch-chart"), branch, t);
}
