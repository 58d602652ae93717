// The person's own move, drawn as soon as the key is pressed. The server owns the game: a key moves the person's
// disc at the world's next step, and the state that shows it comes a network trip later (in real time, a tick and
// a round trip: docs/PERFORMANCE.md, "Key to frame"). So the page draws the disc where the latest key takes it at
// once, and every state from the server corrects it: once a state says the key was applied (last_applied_seq), the
// disc is where the server put it. Only the person's own disc is predicted, by what the server sends
// (welcome.prediction: each key's move and the columns the person's agent may stand on); a move off those cells or
// onto another agent's cell stays put (docs/ENV_CARD.md). Blocks, scores and the other agents are the server's.

export class OwnMove {
  // welcome: the game's welcome; agent: the name of the person's agent ("leader", "leader_1", ...).
  constructor(welcome, agent) {
    this.agent = agent;
    this.width = welcome.width;
    this.height = welcome.height;
    this.others = welcome.look.agents.map((a) => a.name).filter((name) => name !== agent);
    this.moves = welcome.prediction?.moves ?? {};
    [this.first, this.stop] = welcome.prediction?.columns ?? [0, welcome.width];
    this.pending = null;  // the latest key not yet applied: { key, seq }
  }

  // A move key sent with its seq: the disc is drawn where it goes until the server has applied it.
  press(key, seq) {
    if (Object.hasOwn(this.moves, key)) this.pending = { key, seq };
  }

  // The state to draw: `state` itself, or with the person's agent moved by the pending key. A state that applied the
  // key (or a later one: an earlier key superseded) ends the prediction; so does the game's last step.
  shown(state) {
    const applied = state.last_applied_seq !== null && typeof state.last_applied_seq === "object"
      ? state.last_applied_seq[this.agent] : state.last_applied_seq;
    if (this.pending && applied != null && applied >= this.pending.seq) this.pending = null;
    if (!this.pending || state.step >= state.horizon) return state;
    const cell = state[this.agent], [dr, dc] = this.moves[this.pending.key];
    const row = Math.floor(cell / this.width) + dr, col = (cell % this.width) + dc;
    if (row < 0 || row >= this.height || col < this.first || col >= this.stop) return state;
    const target = row * this.width + col;
    if (this.others.some((name) => state[name] === target)) return state;
    return { ...state, [this.agent]: target };
  }
}
