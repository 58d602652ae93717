// Who is who on a study's board, in a participant's words: "You" for the agent they play, "Your AI partner"
// for the AI follower ("The AI leader" when the participant plays the follower), each beside its disc drawn as the board draws it (colors and label from the server's
// `look`: colorgrid.render.look). `agent` is the name of the participant's agent (the study page's view says it).
import { ROLE } from "./sets.js";

export function words(lookValue, agent) {
  // [{agent, text}] in the board's agent order: the participant's own first.
  const assisting = lookValue.agents.find((a) => a.name === agent)?.role === ROLE.FOLLOWER;
  const people = lookValue.agents.map((a) => ({ agent: a, text: a.name === agent ? "You"
    : assisting && a.role === ROLE.LEADER ? "The AI leader (it knows the goal)" : "Your AI partner" }));
  return people.sort((a, b) => (b.agent.name === agent) - (a.agent.name === agent));
}

export function disc(agent) {
  // The agent's disc as a small inline element: its body color, its label in its ink color.
  const element = document.createElement("span");
  element.className = "disc";
  element.dataset.agent = agent.name;
  element.textContent = agent.symbol;
  element.style.background = agent.body;
  element.style.color = agent.ink;
  element.setAttribute("role", "img");
  element.setAttribute("aria-label", `the disc marked ${agent.symbol}`);
  return element;
}

export function drawLegend(container, lookValue, agent) {
  // One line per agent: its disc and who it is ("You", "Your AI partner").
  container.replaceChildren(...words(lookValue, agent).map(({ agent: a, text }) => {
    const row = document.createElement("div");
    row.className = "legend-row";
    row.dataset.who = a.name === agent ? "you" : "partner";
    const label = document.createElement("span");
    label.textContent = text;
    row.append(disc(a), label);
    return row;
  }));
}

export function describe(board, lookValue, agent, colors) {
  // The board in the participant's words, for the canvas's accessible name.
  const where = words(lookValue, agent).map(({ agent: a, text }) => {
    const r = Math.floor(board[a.name] / board.width), c = board[a.name] % board.width;
    return `${text} (${a.symbol}) at row ${r + 1}, column ${c + 1}`;
  });
  return `goal ${board.goal == null ? "unknown" : colors[board.goal]}; ${where.join("; ")}`;
}
