// The episode chart under the replay board: belief lines, the true goal strip, pickup and switch markers,
// and a cursor at the current step. Pure drawing: `drawChart(canvas, data, step, followers, watched)`;
// `stepAt(canvas, data, x)`.
// A person in a follower seat (the timeline's `stated_beliefs` and `probes`): their stated color as a thick step line
// (at 1 while they said that color), each answered probe as a ringed point in its color at its confidence, and
// `watched` ({agent: [T][C]}), an AI follower's goal probabilities watching that seat, as solid lines on the same axis.
// `data` is a replay's timeline: its `look` gives the colors and the agents (in index order, the leaders first).
// A chart shows the leaders (dashed belief lines, pickups above) and the `followers` it is for (solid lines,
// pickups below): every follower unless told (1:1: the follower); the player draws one chart per follower
// with beliefs in teams of several.
import { ROLE } from "./sets.js";

const PAD = { left: 30, right: 8, top: 14, bottom: 26 };

function xOf(canvas, data, t) {
  const w = canvas.width - PAD.left - PAD.right;
  return PAD.left + (w * t) / Math.max(1, data.steps);
}

export function stepAt(canvas, data, x) {
  const w = canvas.width - PAD.left - PAD.right;
  return Math.max(0, Math.min(data.steps, Math.round(((x - PAD.left) / w) * data.steps)));
}

export function followerNames(data) {
  return data.look.agents.filter((agent) => agent.role === ROLE.FOLLOWER).map((agent) => agent.name);
}

export function drawChart(canvas, data, step, followers = followerNames(data), watched = {}) {
  const ctx = canvas.getContext("2d");
  const H = canvas.height, plotH = H - PAD.top - PAD.bottom;
  const yOf = (p) => PAD.top + (1 - p) * plotH;
  ctx.clearRect(0, 0, canvas.width, H);
  ctx.fillStyle = "#fff";
  ctx.fillRect(0, 0, canvas.width, H);
  ctx.strokeStyle = "#ddd";
  ctx.fillStyle = "#666";
  ctx.font = "10px sans-serif";
  for (const p of [0, 0.5, 1]) {
    ctx.beginPath(); ctx.moveTo(PAD.left, yOf(p)); ctx.lineTo(canvas.width - PAD.right, yOf(p)); ctx.stroke();
    ctx.fillText(p.toFixed(1), 4, yOf(p) + 3);
  }
  const palette = data.look.palette;
  const role = Object.fromEntries(data.look.agents.map((agent) => [agent.name, agent.role]));
  const shown = (name) => role[name] === ROLE.LEADER || followers.includes(name);
  // belief lines, one per color, for each shown agent that has beliefs (dashed for leaders, solid for followers)
  for (const [agent, probs] of Object.entries(data.goal_probs || {})) {
    if (!shown(agent)) continue;
    ctx.setLineDash(role[agent] === ROLE.LEADER ? [4, 3] : []);
    drawLines(ctx, canvas, data, probs, yOf);
  }
  ctx.setLineDash([]);
  for (const [agent, probs] of Object.entries(watched)) {  // an AI follower watching the person's seat
    if (shown(agent)) drawLines(ctx, canvas, data, probs, yOf);
  }
  drawPerson(ctx, canvas, data, shown, yOf);
  // the true goal beneath the plot
  const stripY = H - PAD.bottom + 4;
  data.goal.forEach((g, t) => {
    ctx.fillStyle = palette[g];
    const x0 = xOf(canvas, data, t), x1 = xOf(canvas, data, t + 1);
    ctx.fillRect(x0, stripY, Math.max(1, x1 - x0), 8);
  });
  ctx.fillStyle = "#666";
  ctx.fillText("goal", 2, stripY + 8);
  // events: switches (dashes across the plot), pickups (ticks above/below)
  for (const e of data.events) {
    const x = xOf(canvas, data, e.t + 1);
    if (e.type === "switch") {
      ctx.strokeStyle = "#999"; ctx.setLineDash([2, 3]);
      ctx.beginPath(); ctx.moveTo(x, PAD.top); ctx.lineTo(x, H - PAD.bottom); ctx.stroke(); ctx.setLineDash([]);
    } else if (shown(e.agent)) {
      const y = role[e.agent] === ROLE.LEADER ? 2 : H - 12;  // the leaders' above the plot, the followers' below
      ctx.strokeStyle = palette[e.color]; ctx.lineWidth = 2;
      ctx.beginPath();
      if (e.correct) { ctx.moveTo(x, y); ctx.lineTo(x, y + 9); }
      else { ctx.moveTo(x - 3, y); ctx.lineTo(x + 3, y + 9); ctx.moveTo(x + 3, y); ctx.lineTo(x - 3, y + 9); }
      ctx.stroke(); ctx.lineWidth = 1;
    }
  }
  // cursor
  const cx = xOf(canvas, data, step);
  ctx.strokeStyle = "#000"; ctx.lineWidth = 1.5;
  ctx.beginPath(); ctx.moveTo(cx, PAD.top - 4); ctx.lineTo(cx, H - PAD.bottom + 12); ctx.stroke();
  ctx.lineWidth = 1;
  canvas.dataset.cursor = step;
  canvas.dataset.cursorX = cx.toFixed(1);
}

function drawLines(ctx, canvas, data, probs, yOf) {
  // one line per color over the steps: a belief's probabilities
  for (let k = 0; k < data.colors.length; k++) {
    ctx.strokeStyle = data.look.palette[k];
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    probs.forEach((row, t) => { const x = xOf(canvas, data, t), y = yOf(row[k]); t ? ctx.lineTo(x, y) : ctx.moveTo(x, y); });
    ctx.stroke();
  }
}

function drawPerson(ctx, canvas, data, shown, yOf) {
  // The person's stated color: a step line per run of one color (up to 1 where the run starts, along 1, down where it
  // ends); steps before their first statement have none. Probe answers: points at their confidence, ringed in black;
  // a probe missed or left unanswered: a hollow grey ring at 0 on the step that asked. Where each is drawn is kept in
  // the canvas's data-stated-runs and data-probe-points (JSON), for assistive tools and tests.
  const palette = data.look.palette, runs = [], points = [];
  for (const [agent, stated] of Object.entries(data.stated_beliefs || {})) {
    if (!shown(agent)) continue;
    for (let t = 0; t < stated.length;) {
      let end = t + 1;
      while (end < stated.length && stated[end] === stated[t]) end++;
      if (stated[t] != null) runs.push({ agent, color: stated[t], from: t, to: end });
      t = end;
    }
  }
  ctx.lineWidth = 3.5;
  ctx.lineJoin = "round";
  for (const run of runs) {
    const x0 = xOf(canvas, data, run.from), x1 = xOf(canvas, data, run.to);
    ctx.strokeStyle = palette[run.color];
    ctx.beginPath();
    ctx.moveTo(x0, yOf(0)); ctx.lineTo(x0, yOf(1)); ctx.lineTo(x1, yOf(1)); ctx.lineTo(x1, yOf(0));
    ctx.stroke();
    Object.assign(run, { x0: Number(x0.toFixed(1)), x1: Number(x1.toFixed(1)), y: Number(yOf(1).toFixed(1)) });
  }
  ctx.lineJoin = "miter";
  for (const probe of data.probes || []) {
    const agent = probe.agent ?? Object.keys(data.stated_beliefs || {})[0];
    if (!shown(agent)) continue;
    const answered = probe.status === "answered";
    const x = xOf(canvas, data, answered ? probe.answered_step ?? probe.step : probe.step);
    const y = answered ? yOf(probe.confidence) : yOf(0);
    ctx.beginPath();
    ctx.arc(x, y, 5, 0, 2 * Math.PI);
    if (answered) { ctx.fillStyle = palette[probe.color]; ctx.fill(); }
    ctx.strokeStyle = answered ? "#000" : "#888";
    ctx.lineWidth = 1.5;
    ctx.stroke();
    points.push({ agent, status: probe.status, color: probe.color, confidence: probe.confidence,
                  x: Number(x.toFixed(1)), y: Number(y.toFixed(1)) });
  }
  ctx.lineWidth = 1;
  canvas.dataset.statedRuns = JSON.stringify(runs);
  canvas.dataset.probePoints = JSON.stringify(points);
}
