// The episode chart under the replay board: belief lines, the true goal strip, pickup and switch markers,
// and a cursor at the current step. Pure drawing: `drawChart(canvas, data, step, followers)`;
// `stepAt(canvas, data, x)`.
// `data` is a replay's timeline: its `look` gives the colors and the agents (in index order, the leaders first).
// A chart shows the leaders (dashed belief lines, pickups above) and the `followers` it is for (solid lines,
// pickups below): every follower unless told (1:1: the follower); the player draws one chart per follower
// with beliefs in teams of several.

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
  return data.look.agents.filter((agent) => agent.role === "follower").map((agent) => agent.name);
}

export function drawChart(canvas, data, step, followers = followerNames(data)) {
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
  const shown = (name) => role[name] === "leader" || followers.includes(name);
  // belief lines, one per color, for each shown agent that has beliefs (dashed for leaders, solid for followers)
  for (const [agent, probs] of Object.entries(data.goal_probs || {})) {
    if (!shown(agent)) continue;
    ctx.setLineDash(role[agent] === "leader" ? [4, 3] : []);
    for (let k = 0; k < data.colors.length; k++) {
      ctx.strokeStyle = palette[k];
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      probs.forEach((row, t) => { const x = xOf(canvas, data, t), y = yOf(row[k]); t ? ctx.lineTo(x, y) : ctx.moveTo(x, y); });
      ctx.stroke();
    }
  }
  ctx.setLineDash([]);
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
      const y = role[e.agent] === "leader" ? 2 : H - 12;  // the leaders' above the plot, the followers' below
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
