// The study's admin page: progress by arm and condition, quotas, completion times, live games, and
// the data download. Every request carries the admin token (Authorization: Bearer); the token is kept
// in this tab only (sessionStorage) and never appears in a URL.
const $ = (id) => document.getElementById(id);
let token = sessionStorage.getItem("colorgrid-admin-token") ?? "";

async function get(path) {
  const response = await fetch(`/api/study/admin/${path}`, { headers: { Authorization: `Bearer ${token}` } });
  if (!response.ok) throw new Error((await response.json()).detail ?? `refused (${response.status})`);
  return response;
}

function table(element, header, rows) {
  const line = (cells, tag) => {
    const tr = document.createElement("tr");
    for (const cell of cells) {
      const td = document.createElement(tag);
      td.textContent = cell ?? "";
      tr.append(td);
    }
    return tr;
  };
  element.replaceChildren(line(header, "th"), ...rows.map((row) => line(row, "td")));
}

const when = (seconds) => (seconds ? new Date(seconds * 1000).toLocaleString() : "");

async function refresh() {
  const s = await (await get("summary")).json();
  sessionStorage.setItem("colorgrid-admin-token", token);
  $("status").textContent = "";  // an earlier error (a wrong token, a refresh that failed) is over
  $("status").className = "";
  $("login").hidden = true;
  $("dashboard").hidden = false;
  $("study-name").textContent = `${s.title} (${s.study})`;
  $("totals").textContent = `${s.participants.total} started (limit ${s.max_participants}): ` +
    `${s.participants.active} in progress, ${s.participants.completed} completed; ${s.live_games} games live now`;
  const median = s.completion_minutes.median;
  $("times").textContent = median === null ? "no one has completed yet"
    : `completion time: median ${median.toFixed(1)} min (all: ${s.completion_minutes.values.join(", ")})`;
  $("endings").textContent = endings(s.endings, s.ending_words);
  $("refused").textContent = refused(s.refused);
  const mean = (value, digits = 2) => (value == null ? "" : value.toFixed(digits));
  table($("arms"), ["arm", "trials (conditions in order)", "in progress", "completed", "quota", "trials ended",
                    "team score (mean)", "AI partner's net pickups (mean)", "its wrong pickups (mean)",
                    "belief accuracy (mean)", "trials excluded", "participants excluded"],
    s.arms.map((a) => [a.arm, a.label, a.active, a.completed, s.quota ?? "none", a.trials?.games ?? 0,
                       mean(a.trials?.team_score), mean(a.trials?.follower_net_pickups),
                       mean(a.trials?.follower_wrong_pickups), mean(a.trials?.belief_accuracy),
                       excluded(a.excluded.trials, a.excluded.rules), a.excluded.participants]));
  $("servers").hidden = !s.backends;  // several processes behind HAProxy: each one's load and clock
  if (s.backends) {
    table($("backends"), ["process", "address", "state", "live games", "connections", "tick lateness p50 / p99 (ms)",
                          "late ticks", "follower deadline misses", "restarts: process / inference"],
      s.backends.map((b) => [b.name, b.address, b.up ? (b.ready ? "up" : "starting") : `down: ${b.problem}`, b.games,
                             b.connections, b.up ? `${b.tick_lateness_p50_ms} / ${b.tick_lateness_p99_ms}` : "",
                             b.late_ticks, b.deadline_misses,
                             b.up ? `${b.restarts ?? 0} / ${b.inference_restarts ?? 0}` : ""]));
  }
  const factors = Object.keys(s.conditions[0] ?? {}).filter((k) => k !== "label");
  table($("conditions"), ["condition", ...factors], s.conditions.map((c) => [c.label, ...factors.map((k) => String(c[k]))]));
  table($("recent"), ["participant", "arm", "status", "page", "started", "last seen", "completed"],
    s.recent.map((p) => [p.pid, p.arm, p.status, p.step + 1, when(p.started), when(p.updated), when(p.completed)]));
}

function endings({ counted, played_again: again }, words) {
  // "Games that count: 40 complete, 1 idle. Played again: 1 lost with a process that stopped (server_lost), ..."
  // in the server's words for each ending (the summary's ending_words)
  const list = (counts) => Object.entries(counts).map(([ended, n]) => `${n} ${words[ended] ?? ended}`).join(", ");
  return `Games that count: ${list(counted) || "none yet"}. Played again: ${list(again) || "none"}.`;
}

function excluded(trials, rules) {
  // "2 (away 1, idle 1)": trials the study's [exclusions] rules exclude, and the rows of each rule (a trial may break two)
  const each = Object.entries(rules).filter(([rule]) => rule !== "failed_checks").map(([rule, n]) => `${rule} ${n}`);
  return each.length ? `${trials} (${each.join(", ")})` : String(trials);
}

function refused(counts) {
  // "Refused at the door: 2 full, 1 screening:viewport." (the reasons the server logged)
  const list = Object.entries(counts).map(([reason, n]) => `${n} ${reason}`).join(", ");
  return `Refused at the door: ${list || "none"}.`;
}

async function open() {
  token = $("token").value.trim();
  try {
    await refresh();
    setInterval(() => refresh().catch((err) => { $("status").textContent = err.message; }), 5000);
  } catch (err) {
    $("status").textContent = err.message;
    $("status").className = "error";
  }
}

$("open").addEventListener("click", open);
$("download").addEventListener("click", async () => {
  $("download-status").textContent = "preparing...";
  try {
    const blob = await (await get("export.zip")).blob();
    const link = Object.assign(document.createElement("a"), { href: URL.createObjectURL(blob), download: "study-data.zip" });
    link.click();
    $("download-status").textContent = `downloaded (${Math.round(blob.size / 1024)} KB)`;
  } catch (err) {
    $("download-status").textContent = err.message;
  }
});
if (token) { $("token").value = token; open(); }
