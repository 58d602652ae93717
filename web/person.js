// The person on the replay player: in a game with a person in a follower seat (the timeline's `stated_beliefs`), the
// "person and AI" panel gives this game's measures of the person beside the AI follower chosen in the follower menu
// watching the person's seat (GET /api/replays/{id}/people?follower=: the same measures `colorgrid replay rescore`
// pools over games), and hands that follower's beliefs to the chart, drawn on the person's axis. A game rescore sets
// apart (a study's practice, the goal shown) is named in the server's words (`set_apart_words`), not the page's.
// `setupPerson(id, data, redraw)` once; `redraw(watched)` draws the chart again with {agent: [T][C]}.

const $ = (id) => document.getElementById(id);

// How each measure is written; its words and the rows' order come from the timeline (`person_measure_words`).
const pct = (v) => `${(100 * v).toFixed(1)}%`;
const FORMS = {
  accuracy: pct,
  accuracy_all_steps: pct,
  probe_accuracy: pct,
  log_loss: (v) => v.toFixed(3),
  brier: (v) => v.toFixed(3),
  switch_lags: (v) => (v.length ? v.join(", ") : "none caught"),
  net_pickups: (v) => (v > 0 ? `+${v}` : `${v}`),
};
let asked = 0;

export async function setupPerson(replayId, data, redraw) {
  const people = Object.keys(data.person_measures ?? {});
  if (!people.length) return;
  $("person-panel").hidden = false;
  $("chart-note").textContent = "Thick step lines: the color the person said is the goal (at 1 while they said it). " +
    "Points: the person's probe answers, in the color they chose at the confidence they gave (a grey ring: a probe " +
    "not answered). Thin lines: the AI follower chosen in the menu, watching the person's seat. Strip below: the true " +
    "goal. Ticks: pickups. Dashes: goal switches. Click to jump. Keys: space play/pause, \u2190/\u2192 step, " +
    "Home/End, +/\u2212 speed, t trails.";
  const menu = $("branch-follower");
  if (!menu.options.length) {  // no "branch here" (a team): the menu is the person panel's alone
    const response = await fetch("/api/options");
    if (!response.ok) { showProblem(await detail(response)); return; }
    const options = await response.json();
    menu.replaceChildren(...options.followers.map((name) => new Option(name, name)));
    menu.value = options.default_follower;
    $("branch-controls").hidden = false;
    $("branch-here").hidden = true;
  }
  fillTable(data, people, null, null);
  menu.addEventListener("change", () => measure(replayId, data, people, redraw));
  await measure(replayId, data, people, redraw);
}

async function detail(response) {
  try { return (await response.json()).detail ?? response.statusText; } catch { return response.statusText; }
}

function showProblem(text) {
  $("person-status").textContent = text;
  $("person-status").className = text ? "note error" : "note";
}

async function measure(replayId, data, people, redraw) {
  const follower = $("branch-follower").value, mine = ++asked;  // a later choice wins over one still loading
  $("person-ai").textContent = follower;
  showProblem(`${follower} watches the person's seat\u2026`);
  const response = await fetch(`/api/replays/${encodeURIComponent(replayId)}/people?follower=` +
                               encodeURIComponent(follower));
  const body = response.ok ? await response.json() : null;
  if (mine !== asked) return;
  if (!body) {
    showProblem(`${follower} cannot be set beside the person: ${await detail(response)}`);
    fillTable(data, people, null, follower);
    redraw({});
    return;
  }
  showProblem(Object.values(body.seats).some((seat) => seat.follower == null)
    ? `${follower} forms no belief: only its pickups can be set beside the person's` : "");
  fillTable(data, people, body.seats, follower);
  const watched = Object.fromEntries(Object.entries(body.seats).filter(([, seat]) => seat.beliefs)
    .map(([agent, seat]) => [agent, seat.beliefs]));
  $("person-panel").dataset.follower = follower;
  redraw(watched);
}

function fillTable(data, people, seats, follower) {
  // One table per person's seat (one in 1:1): a row per measure, the person's column and the AI follower's.
  $("person-tables").replaceChildren(...people.map((agent) => {
    const person = data.person_measures[agent], seat = seats?.[agent];
    const ai = seat ? { ...(seat.follower ?? {}), net_pickups: seat.net_pickups } : {};
    const table = document.createElement("table");
    table.className = "person-table";
    table.dataset.agent = agent;
    const head = table.createTHead().insertRow();
    for (const text of [people.length > 1 ? agent : "", "person", follower ?? "AI follower"]) {
      const th = document.createElement("th");
      th.textContent = text;
      head.appendChild(th);
    }
    const body = table.createTBody();
    for (const [key, words] of data.person_measure_words) {
      const form = FORMS[key] ?? String;
      const row = body.insertRow();
      row.dataset.measure = key;
      row.insertCell().textContent = words;
      for (const [who, values] of [["person", person], ["ai", ai]]) {
        const cell = row.insertCell();
        cell.dataset.who = who;
        const value = values[key];
        cell.textContent = value == null ? "\u2013" : form(value);
      }
    }
    const facts = document.createElement("p");
    facts.className = "note";
    const apart = seat?.set_apart_words;  // the server's words for a game rescore sets apart (practice, goal shown)
    facts.textContent = `The person said a color at ${person.stated_steps} of ${person.steps} steps and answered ` +
      `${person.probes_answered} of ${person.probes_asked} probes; ${person.switches} goal switches.` +
      (apart ? ` This is ${apart}: rescore reports it apart from the person's figures.` : "");
    const wrap = document.createElement("div");
    wrap.append(table, facts);
    return wrap;
  }));
}
