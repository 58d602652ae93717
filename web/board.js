// Draws a ColorGrid board on a canvas, by the same rules as colorgrid/render.py: floor, colored blocks,
// each agent of the team as a disc in its role's colors with its label (1:1: L, F; other teams: L1, L2, F1, ...),
// a frame in the goal color; `agentBadge` draws a disc beside text. The colors and the agents are the server's (`look`: /api/options, the welcome
// message, a replay's timeline), set once with `setLook`. `describeBoard` says the same in words. The study's page
// asks for a wider frame, larger discs and a short trail behind its AI partner (`drawBoard`'s options).
let look = null;

export function setLook(value) {
  look = value;
}

// `frame`: the goal frame's width in pixels; `discCells`: each disc's width in cells (1: its own cell; wider ones
// overlap their neighbours); `labelPx`: the disc's label's size in pixels (by default the disc's width less 6);
// `trails`: {agent name: [cell, ...]} oldest first, drawn as fading dots under the discs. Returns the cell's size in
// pixels.
export function drawBoard(canvas, board, { frame = 4, discCells = 1, labelPx = null, trails = {} } = {}) {
  const { height, width, blocks, goal } = board;
  const border = frame;
  const cell = Math.floor(Math.min((canvas.width - 2 * border) / width, (canvas.height - 2 * border) / height));
  const ctx = canvas.getContext("2d");
  ctx.fillStyle = goal == null ? "#999" : look.palette[goal];
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  ctx.fillStyle = look.floor;
  ctx.fillRect(border, border, cell * width, cell * height);
  ctx.strokeStyle = look.grid;
  ctx.lineWidth = 1;
  ctx.beginPath();
  for (let r = 0; r <= height; r++) { ctx.moveTo(border, border + r * cell + 0.5); ctx.lineTo(border + width * cell, border + r * cell + 0.5); }
  for (let c = 0; c <= width; c++) { ctx.moveTo(border + c * cell + 0.5, border); ctx.lineTo(border + c * cell + 0.5, border + height * cell); }
  ctx.stroke();
  const margin = Math.max(1, Math.floor(cell / 8));
  for (let i = 0; i < blocks.length; i++) {
    const ch = blocks[i];
    if (ch === ".") continue;
    const r = Math.floor(i / width), c = i % width;
    ctx.fillStyle = look.palette[Number(ch)];
    ctx.fillRect(border + c * cell + margin, border + r * cell + margin, cell - 2 * margin, cell - 2 * margin);
  }
  for (const agent of look.agents) drawTrail(ctx, border, cell, width, trails[agent.name] ?? [], agent);
  for (const agent of look.agents) drawAgent(ctx, border, cell, width, board[agent.name], agent, discCells, labelPx);
  return cell;
}

function drawTrail(ctx, border, cell, width, cells, agent) {
  // The agent's last cells, oldest faintest: small dots in its body color, ringed in black.
  cells.forEach((index, k) => {
    const r = Math.floor(index / width), c = index % width;
    ctx.globalAlpha = 0.3 + (0.5 * (k + 1)) / cells.length;
    ctx.beginPath();
    ctx.arc(border + c * cell + cell / 2, border + r * cell + cell / 2, cell / 4, 0, 2 * Math.PI);
    ctx.fillStyle = agent.body;
    ctx.fill();
    ctx.strokeStyle = "#000";
    ctx.stroke();
  });
  ctx.globalAlpha = 1;
}

function drawAgent(ctx, border, cell, width, index, agent, discCells = 1, labelPx = null) {
  const r = Math.floor(index / width), c = index % width;
  const x = border + c * cell + cell / 2, y = border + r * cell + cell / 2;
  const wide = discCells * cell;
  ctx.beginPath();
  ctx.arc(x, y, wide / 2 - 0.5, 0, 2 * Math.PI);
  ctx.fillStyle = agent.body;
  ctx.fill();
  ctx.strokeStyle = "#000";
  ctx.lineWidth = discCells > 1 ? 2 : 1;
  ctx.stroke();
  ctx.lineWidth = 1;
  ctx.fillStyle = agent.ink;
  let size = labelPx ?? Math.max(8, Math.round(wide) - 6);
  ctx.font = `bold ${size}px sans-serif`;
  const room = 0.8 * wide, measured = ctx.measureText(agent.symbol).width;
  if (agent.symbol.length > 1 && measured > room) {  // two-character labels (L1, F2) shrink to fit their disc
    size = Math.max(6, Math.floor((size * room) / measured));
    ctx.font = `bold ${size}px sans-serif`;
  }
  ctx.textAlign = "center";
  ctx.textBaseline = "middle";
  ctx.fillText(agent.symbol, x, y + 1);
}

export function agentBadge(agent) {
  // An agent's disc in words' size: its label on its role's colors, as the board draws it (legends, scores).
  const badge = document.createElement("span");
  badge.className = "agent-badge";
  badge.textContent = agent.symbol;
  badge.style.background = agent.body;
  badge.style.color = agent.ink;
  return badge;
}

export function describeBoard(board, colors) {
  // The board in words, for the canvas's accessible name: the goal, then where each agent stands.
  const where = look.agents.map((agent) => {
    const r = Math.floor(board[agent.name] / board.width), c = board[agent.name] % board.width;
    return `${agent.symbol} (${agent.name}) at row ${r + 1}, column ${c + 1}`;
  });
  return `goal ${board.goal == null ? "unknown" : colors[board.goal]}; ${where.join("; ")}`;
}

export function drawBelief(container, probs, colors, { percent = false } = {}) {
  // One labelled bar per color; `probs` null hides them, a null entry draws its bar empty (no belief yet);
  // `percent` writes each value as a percentage (48%) instead of a probability (0.48).
  container.replaceChildren();
  if (!probs) return;
  probs.forEach((p, k) => {
    const row = document.createElement("div");
    row.className = "belief-row";
    row.dataset.color = colors[k];
    const value = p == null ? "–" : percent ? `${Math.round(100 * p)}%` : p.toFixed(2);
    const fill = `width:${(100 * (p ?? 0)).toFixed(1)}%;background:${look.palette[k]}`;
    row.innerHTML = `<span class="belief-name">${colors[k]}</span>
      <span class="belief-track"><span class="belief-fill" style="${fill}"></span></span>
      <span class="belief-value">${value}</span>`;
    container.appendChild(row);
  });
}
