// Who is who on the play page: the room card (its code, the link to share, the seats, Ready), the rows beside
// the board (every agent's disc with who plays it: "you", "your AI partner", "the other person"), and the
// server's room words as sentences. The server says who sits where (`room`, `welcome`, `seats` messages);
// this module only draws it. See docs/SERVER_PROTOCOL.md.
import { agentBadge } from "./board.js";
import { ROLE, ROOM_SEAT_STATUS, SEAT_STATUS } from "./sets.js";

const $ = (id) => document.getElementById(id);
// The room's words: the server's (/api/options' `room_words`: each room error, why a room closed, each seat's
// status), set once the page has its options. The page keeps no list of them of its own.
let words = { errors: {}, closed: {}, seats: {} };

export function setRoomWords(roomWords) {
  words = { ...words, ...roomWords };
}

// Whether this page opened the room (the opener sits in the first seat): only they are asked to share its link.
export function openedRoom(msg) {
  return msg.seats[0]?.agent === msg.you;
}

// The room card for a `room` message; returns whether this page's seat is ready.
export function showRoom(msg, options) {
  $("share").hidden = !openedRoom(msg);
  $("joined").hidden = openedRoom(msg);
  $("room-code").textContent = msg.code;
  const link = new URL(msg.link, location.origin).href;
  $("room-link").href = link;
  $("room-link").textContent = link;
  const mode = options.modes.find((m) => m.value === msg.mode)?.label ?? msg.mode;
  const follower = options.follower_info.find((f) => f.value === msg.follower)?.label ?? msg.follower;
  $("room-settings").textContent = `${msg.team}: ${mode}, ${msg.horizon} steps, setting ${msg.preset}, ` +
    `AI partner: ${follower}`;
  $("room-seats").replaceChildren(...msg.seats.map((seat) => {
    const item = document.createElement("li");
    item.dataset.status = seat.status;
    const you = seat.agent === msg.you ? " (you)" : "";
    item.textContent = `${seat.symbol}${you}: ${words.seats[seat.status] ?? seat.status}`;
    return item;
  }));
  const mine = msg.seats.find((seat) => seat.agent === msg.you);
  const ready = mine?.status === ROOM_SEAT_STATUS.READY;
  $("ready").textContent = ready ? "Not ready" : "Ready";
  $("ready").disabled = msg.starting_in_s != null;
  return ready;
}

// The rows beside the board: one per agent (its disc, who plays it, its score holder); this person's disc is
// ringed as on the board and has the id "you".
export function showAgents(game) {
  $("agent-scores").replaceChildren(...game.look.agents.map((agent) => {
    const row = document.createElement("div");
    row.className = "row agent";
    row.dataset.agent = agent.name;
    const who = document.createElement("span");
    const badge = agentBadge(agent);
    if (agent.name === game.agent) {
      badge.id = "you";
      badge.classList.add("you-badge");
    }
    const words = document.createElement("span");
    words.className = "who";
    who.append(badge, " ", words);
    const score = document.createElement("span");
    score.className = "score";
    row.append(who, score);
    return row;
  }));
  showSeats(game, game.seats ?? []);
}

// Who an agent is to this page's person: "you", "the other person", "a scripted leader" (in the seat of a
// person who left), "the AI leader" (one you lead beside: the welcome's `leaders`) or "your AI partner" (every AI
// follower of the team).
export function whoIs(game, name) {
  if (name === game.agent) return "you";
  if (game.leaders?.[name]) return "the AI leader";
  const seat = game.seats?.find((s) => s.agent === name);
  if (seat) return seat.status === SEAT_STATUS.LEFT ? "a scripted leader" : "the other person";
  return game.look.agents.find((a) => a.name === name)?.role === ROLE.LEADER ? "the other person" : "your AI partner";
}

// Who plays each agent now (a `seats` message, or the welcome's seats; none in a game of one person).
export function showSeats(game, seats) {
  game.seats = seats;
  const notes = [];
  for (const agent of game.look.agents) {
    const seat = seats.find((s) => s.agent === agent.name);
    if (seat && seat.status !== SEAT_STATUS.PLAYING && agent.name !== game.agent) {
      notes.push(`${agent.symbol} ${words.seats[seat.status] ?? seat.status}`);
    }
    document.querySelector(`#agent-scores [data-agent="${agent.name}"] .who`).textContent = whoIs(game, agent.name);
  }
  $("seats-note").textContent = notes.join("; ");
}

export function showScores(game, scores, fmt) {
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
    title.append(agentBadge(agent), ` ${whoIs(game, agent.name)}`);
    const bars = document.createElement("div");
    block.append(title, bars);
    container.appendChild(block);
    drawBelief(bars, beliefs[agent.name], game.colors);
  }
}

// A ring around this page's own agent on the board (drawn as web/board.js draws agents: a disc per cell), in the
// color of the ring around "you" in the legend (.you-badge in web/style.css).
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
  return Object.hasOwn(words.errors, msg.code ?? "") ? words.errors[msg.code] : null;
}

// A `room_closed` reason as a sentence.
export function plainRoomClosed(msg) {
  return Object.hasOwn(words.closed, msg.reason ?? "") ? words.closed[msg.reason] : `The room closed (${msg.reason}).`;
}
