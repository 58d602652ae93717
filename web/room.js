// Teams on the play page: the room card (its code, the link to share, the seats, Ready), the team's rows
// beside the board (every agent with its label, "you" marked), and the server's room words as sentences.
// The server says who sits where (`room`, `welcome`, `seats` messages); this module only draws it.
// See docs/SERVER_PROTOCOL.md.

const $ = (id) => document.getElementById(id);
const SEAT_WORDS = { open: "waiting for a person", joined: "joined", ready: "ready", playing: "playing",
                     reconnecting: "reconnecting...", left: "left: a scripted leader plays on" };

// The room card for a `room` message; returns whether this page's seat is ready.
export function showRoom(msg, options) {
  $("room-code").textContent = msg.code;
  const link = new URL(msg.link, location.origin).href;
  $("room-link").href = link;
  $("room-link").textContent = link;
  const mode = options.modes.find((m) => m.value === msg.mode)?.label ?? msg.mode;
  const follower = options.follower_info.find((f) => f.value === msg.follower)?.label ?? msg.follower;
  $("room-settings").textContent = `${msg.team}: ${mode}, ${msg.horizon} steps, setting ${msg.preset}, ` +
    `AI follower: ${follower}`;
  $("room-seats").replaceChildren(...msg.seats.map((seat) => {
    const item = document.createElement("li");
    item.dataset.status = seat.status;
    const you = seat.agent === msg.you ? " (you)" : "";
    item.textContent = `${seat.symbol}${you}: ${SEAT_WORDS[seat.status] ?? seat.status}`;
    return item;
  }));
  const mine = msg.seats.find((seat) => seat.agent === msg.you);
  const ready = mine?.status === "ready";
  $("ready").textContent = ready ? "Not ready" : "Ready";
  $("ready").disabled = msg.starting_in_s != null;
  return ready;
}

// The rows beside the board in a team game: one per agent (its symbol, who plays it, its score holder).
export function showTeam(game, followerLabel) {
  const you = game.look.agents.find((a) => a.name === game.agent);
  $("you").textContent = you.symbol;
  $("agent-scores").replaceChildren(...game.look.agents.map((agent) => {
    const row = document.createElement("div");
    row.className = "row agent";
    row.dataset.agent = agent.name;
    const who = document.createElement("span");
    who.className = agent.name === game.agent ? "you" : "";
    const score = document.createElement("span");
    score.className = "score";
    row.append(who, score);
    return row;
  }));
  showSeats(game, game.seats, followerLabel);
}

// Who plays each agent now (a `seats` message, or the welcome's seats).
export function showSeats(game, seats, followerLabel) {
  game.seats = seats;
  const notes = [];
  for (const agent of game.look.agents) {
    const seat = seats.find((s) => s.agent === agent.name);
    let who = followerLabel;
    if (seat) {
      who = agent.name === game.agent ? "you" : seat.status === "left" ? "scripted leader" : "the other person";
      if (seat.status !== "playing" && agent.name !== game.agent) {
        notes.push(`${agent.symbol} ${SEAT_WORDS[seat.status]}`);
      }
    }
    document.querySelector(`#agent-scores [data-agent="${agent.name}"] span`).textContent = `${agent.symbol} (${who})`;
  }
  $("seats-note").textContent = notes.join("; ");
}

export function showTeamScores(game, scores, fmt) {
  for (const agent of game.look.agents) {
    document.querySelector(`#agent-scores [data-agent="${agent.name}"] .score`).textContent = fmt(scores[agent.name]);
  }
}

// One belief block per AI follower: `beliefs` maps follower names to probabilities (or null).
export function drawBeliefs(container, beliefs, game, drawBelief) {
  container.replaceChildren();
  if (!beliefs) return;
  for (const agent of game.look.agents) {
    if (!(agent.name in beliefs)) continue;
    const block = document.createElement("div");
    block.className = "belief-agent";
    block.dataset.agent = agent.name;
    const title = document.createElement("div");
    title.className = "belief-title";
    title.textContent = agent.symbol;
    const bars = document.createElement("div");
    block.append(title, bars);
    container.appendChild(block);
    drawBelief(bars, beliefs[agent.name], game.colors);
  }
}

// A ring around this page's own agent on the board (drawn as web/board.js draws agents: a disc per cell).
export function markYou(canvas, cell, width, index) {
  const ctx = canvas.getContext("2d");
  const border = 4, r = Math.floor(index / width), c = index % width;
  ctx.beginPath();
  ctx.arc(border + c * cell + cell / 2, border + r * cell + cell / 2, cell / 2 + 1.5, 0, 2 * Math.PI);
  ctx.strokeStyle = "#ffb000";
  ctx.lineWidth = 3;
  ctx.stroke();
  ctx.lineWidth = 1;
}

// The server's room errors as sentences (null: not a room error).
export function plainRoomError(msg) {
  return {
    bad_room_code: "That is not a room code: check the link or the code you were sent.",
    room_not_found: "No room with that code is waiting: it may have expired. Ask for a new link.",
    room_full: "That room is full: everyone it needs has joined.",
    room_started: "That room's game has already started.",
  }[msg.code] ?? null;
}

// A `room_closed` reason as a sentence.
export function plainRoomClosed(msg) {
  return {
    expired: "The room closed: its game did not start in time. Open a new one.",
    server_shutdown: "The server is restarting: try again in a minute.",
    failed: "The room's game could not start: open a new room.",
  }[msg.reason] ?? `The room closed (${msg.reason}).`;
}

export const LEFT_ENDING = "You left the game; it goes on with a scripted leader in your place.";
