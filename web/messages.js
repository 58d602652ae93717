// What the server says, in words a player understands. The protocol's own text (code: message) stays
// available to researchers: callers put it in the status line's `title` and the console. A refusal with no words of
// its own here is shown with the server's reason, never in place of it.

const RELOAD = "The page and the server do not understand each other: reload the page.";
const NOT_OFFERED = "That choice is not offered any more: reload the page.";

// "The server refused: probes '10,abc' is not a probe plan: ...": the server's reason, without the message type it
// names first ("new_game: ").
export function refusal(msg) {
  const reason = (msg.message ?? "").replace(/^[a-z_]+: /, "");
  return reason ? `The server refused: ${reason}` : "The server refused that.";
}

export function stepsMessage(maxHorizon) {
  return `Steps must be between 1 and ${maxHorizon}.`;
}

// `msg` is an `error` or `full` message; `maxHorizon` is /api/options' horizon.max.
export function plainError(msg, maxHorizon) {
  const text = msg.message ?? "";
  if (msg.type === "full") {
    return /shutting down/.test(text) ? "The server is restarting: try again in a minute."
      : "The server is full: try again in a minute.";
  }
  switch (msg.code) {
    case "invalid_message":
      if (/^new_game: horizon\b/.test(text)) return stepsMessage(maxHorizon);
      if (/^new_game: (follower|preset|mode)\b/.test(text)) return NOT_OFFERED;
      return `${refusal(msg)} (${RELOAD})`;
    case "rejected": {
      const wait = text.match(/too many new games.*try again in (\d+) s/);
      if (wait) return `You started many games in a short time: wait ${wait[1]} s and start again.`;
      if (/^no live game/.test(text)) return "This game is over: start a new one.";
      if (/already has a live game/.test(text)) return "A game is already running in this tab.";
      if (/^no game with that id/.test(text)) return "Your last game could not be resumed (it ended or waited too long): start a new one.";
      if (/unknown (follower|preset)|must be one of/.test(text)) return NOT_OFFERED;
      return refusal(msg);
    }
    case "rate_limited": return "Too many keys at once: some were skipped.";
    case "bad_key":
      return /not a move or a color/.test(text) ? "Move with the arrow keys or W A S D; say the goal with its number key."
        : "Move with the arrow keys or W A S D.";
    case "bad_belief": return "Choose one of the colors shown.";
    case "bad_probe":
      if (/confidence/.test(text)) return "Choose how sure you are: from a guess to certain.";
      if (/^color/.test(text)) return "Choose one of the colors shown.";
      return "That question was already closed.";
    case "internal": return "Something went wrong on the server; the game goes on.";
    default: return `${refusal(msg)} (${RELOAD})`;  // bad_json, unknown_type, too_large: the page sent it wrong
  }
}

// How games end, in words: the server's (/api/options' `endings`, one per ending it may send), set once the page
// has its options. The page keeps no list of endings of its own.
let endings = {};

export function setEndings(words) {
  endings = words ?? {};
}

// A `game_over` reason as a sentence.
export function plainEnding(reason) {
  return endings[reason] ?? `The game ended (${reason}).`;
}
