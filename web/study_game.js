// A study's game, drawn for someone who has never seen ColorGrid: the board with a wide frame in the goal color, each
// disc inside its own cell with a large label, a short trail behind their AI partner, a notice when the goal changes,
// which game this is, and what the partner believes, in words. Everything is laid out when the game starts (the
// welcome) and nothing moves after: the belief panel is there from the first step of a game that shows it. web/study.js hands it the server's messages.
import { drawBelief, drawBoard } from "./board.js";

const $ = (id) => document.getElementById(id);
export const FRAME = 16;    // the goal frame's width in pixels: seen from the corner of an eye
const LABEL_OF_CELL = 0.8;  // a disc's label, as a share of the cell: "L" 13 px high in a 16 px disc
const BOARD_PIXELS = 512;   // the board's cells, without the frame
const TRAIL = 6;            // how many of the AI partner's last cells are drawn behind it
const NEWS_MS = 4000;       // how long "The goal is now blue" stays over the board
let newsTimer = null;

export function gameName(view) {
  // Which game this is: "Practice game (it does not count)", "Game 2 of 4".
  if (view.kind === "practice") return "Practice game (it does not count)";
  return `Game ${view.trial_index + 1} of ${view.trials}`;
}

export function startGame(game, view) {
  // At the welcome: the board's size, which game it is, and the belief panel, all fixed for the whole game.
  const canvas = $("board");
  const cell = Math.max(8, Math.floor(BOARD_PIXELS / Math.max(game.width, game.height)));
  canvas.width = game.width * cell + 2 * FRAME;
  canvas.height = game.height * cell + 2 * FRAME;
  game.cell = cell;
  $("game-name").textContent = gameName(view);
  game.partners = game.look.agents.filter((a) => a.name !== view.agent).map((a) => a.name);
  game.trails = Object.fromEntries(game.partners.map((name) => [name, []]));
  game.last = null;
  hideNews();  // a notice of the last game's goal is not this game's
  $("belief-panel").hidden = !(game.show_belief && view.game?.has_belief);
  if (!$("belief-panel").hidden) showBelief(game, null);
}

export function drawState(game, state) {
  // One state: the board (frame, discs, the partners' trails), the notice of a new goal, the belief.
  for (const name of game.partners) {
    const trail = game.trails[name];
    if (game.last && game.last[name] !== state[name]) trail.push(game.last[name]);
    trail.splice(0, Math.max(0, trail.length - TRAIL));
  }
  if (game.last && game.last.goal !== state.goal) announceGoal(game, state.goal);
  game.last = state;
  for (const agent of game.look.agents) $("board").dataset[agent.name] = state[agent.name];  // for tools and tests
  drawBoard($("board"), { height: game.height, width: game.width, ...state },
            { frame: FRAME, labelPx: Math.round(LABEL_OF_CELL * game.cell), trails: game.trails });
  if (!$("belief-panel").hidden) showBelief(game, state.belief ?? null);
}

function announceGoal(game, goal) {
  // "The goal is now [blue]" over the board for a few seconds, read out by screen readers; the goal row lights up.
  const swatch = Object.assign(document.createElement("span"), { className: "swatch" });
  swatch.style.background = game.look.palette[goal];
  const name = Object.assign(document.createElement("b"), { textContent: game.colors[goal] });
  const news = $("goal-news");
  news.replaceChildren("The goal is now ", swatch, " ", name);
  news.style.borderColor = game.look.palette[goal];
  news.hidden = false;
  document.querySelector(".goal-row").classList.add("changed");
  clearTimeout(newsTimer);
  newsTimer = setTimeout(hideNews, NEWS_MS);
}

function hideNews() {
  clearTimeout(newsTimer);
  $("goal-news").hidden = true;
  document.querySelector(".goal-row").classList.remove("changed");
}

export function beliefWords(probs, colors) {
  // What the AI partner believes, in a sentence: "Your AI partner thinks the goal is green (48% sure)."
  if (!probs) return "Your AI partner has no guess yet: it watches what you do.";
  const pct = (p) => `${Math.round(100 * p)}%`;
  const [[p1, k1], [p2, k2] = [0, k1]] = probs.map((p, k) => [p, k]).sort((a, b) => b[0] - a[0]);
  if (p1 - p2 < 0.05) return `Your AI partner is unsure: ${colors[k1]} (${pct(p1)}) or ${colors[k2]} (${pct(p2)}).`;
  return `Your AI partner thinks the goal is ${colors[k1]} (${pct(p1)} sure).`;
}

function showBelief(game, probs) {
  // The sentence, and a bar per color with its percentage (empty bars before the first guess).
  $("belief-words").textContent = beliefWords(probs, game.colors);
  drawBelief($("belief"), probs ?? game.colors.map(() => null), game.colors, { percent: true });
}
