// The replay list: filters, sorting and pages over /api/replays. A branch (a replay continued from a step with
// another follower) is listed as a branch, with its parent and the step where it leaves it.
import { queryParam } from "./params.js";

const $ = (id) => document.getElementById(id);
const PAGE = 25;
let offset = 0;
let latest = 0; // the last list request sent: only its answer is shown

async function load() {
  const request = ++latest;
  const params = new URLSearchParams({ sort: $("sort").value, order: $("order").value, offset, limit: PAGE });
  for (const name of ["source", "follower", "collection", "setting", "branch_of"]) {
    if ($(name).value) params.set(name, $(name).value);
  }
  const data = await (await fetch(`/api/replays?${params}`)).json();
  // answers can come back out of order (a busy server, a larger page): one to an older filter is dropped, so the
  // list always shows what the filters say now
  if (request !== latest) return;
  const highlight = queryParam("id");
  $("list").tBodies[0].replaceChildren(...data.items.map((item) => row(item, item.id === highlight)));
  $("page").textContent = `${data.total ? offset + 1 : 0}-${Math.min(offset + PAGE, data.total)} of ${data.total}`;
  $("prev").disabled = offset === 0;
  $("next").disabled = offset + PAGE >= data.total;
}

async function loadSettings() {
  // the server's presets join the two settings every replay has (asymmetric or symmetric)
  const options = await (await fetch("/api/options")).json();
  const select = $("setting");
  const listed = new Set([...select.options].map((o) => o.value));
  select.append(...options.presets.filter((p) => !listed.has(p)).map((p) => new Option(p, p)));
}

function row(item, highlight) {
  const tr = document.createElement("tr");
  tr.dataset.id = item.id;
  if (highlight) tr.className = "highlight";
  const cells = item.error
    ? [item.id, "-", "-", "-", "-", "-", "-", "-", `invalid: ${item.error}`]
    : [item.id, item.source, settingTitle(item.setting), branchOf(item.branch_of), item.leader, item.follower,
       item.steps, item.final.team_score, item.ended];
  cells.forEach((value, i) => {
    const td = document.createElement("td");
    if (i === 0) td.appendChild(link(value, "open"));
    else td.append(value);
    tr.appendChild(td);
  });
  const files = document.createElement("td");
  const id = encodeURIComponent(item.id);
  files.innerHTML = `<a href="/api/replays/${id}">json</a> <a href="/api/replays/${id}/export?format=gif">gif</a> <a href="/api/replays/${id}/export?format=mp4">mp4</a>`;
  tr.appendChild(files);
  return tr;
}

function settingTitle(setting) {
  // a group of replays that is no preset (the recipe ablation's followers, each named after its arm in the follower
  // column) is titled by its option in the setting filter
  if (!setting) return "";
  const option = [...$("setting").options].find((o) => o.value === setting);
  return option ? option.text : setting;
}

function link(replayId, className = "", step = null) {
  const a = document.createElement("a");
  a.href = `/replay?id=${encodeURIComponent(replayId)}` + (step != null ? `&step=${step}` : "");
  a.className = className;
  a.textContent = replayId;
  return a;
}

function branchOf(origin) {
  // "PARENT from step T": the parent (a link to it at that step when it is a replay id; a branch made from a file
  // names the file)
  const cell = document.createElement("span");
  if (!origin) return cell;
  cell.className = "branch-of";
  cell.dataset.parent = origin.parent ?? "";
  cell.dataset.step = origin.step ?? "";
  const isId = origin.parent && !origin.parent.endsWith(".json") && !origin.parent.includes("/");
  cell.append(isId ? link(origin.parent, "parent", origin.step) : origin.parent ?? "?", ` from step ${origin.step}`);
  return cell;
}

for (const id of ["source", "sort", "order", "collection", "setting"]) $(id).addEventListener("change", () => { offset = 0; load(); });
for (const id of ["follower", "branch_of"]) $(id).addEventListener("input", () => { offset = 0; load(); });
$("branch_of").value = queryParam("branch_of") ?? "";  // /replays?branch_of=ID: the branches of one replay
$("prev").addEventListener("click", () => { offset = Math.max(0, offset - PAGE); load(); });
$("next").addEventListener("click", () => { offset += PAGE; load(); });
loadSettings();
load();
