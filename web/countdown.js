// The 3-2-1 before a real-time game: shown by the page before it asks the server for the game, so the
// world (the server's) does not move while the player gets ready. See docs/SERVER_PROTOCOL.md.

export function countdown(element, from = 3, stepMs = 1000) {
  // Shows from, ..., 1 in `element`, one a `stepMs`; resolves when the last has been shown its time.
  element.hidden = false;
  return new Promise((resolve) => {
    let n = from;
    const show = () => {
      if (n === 0) return resolve();
      element.textContent = String(n--);
      setTimeout(show, stepMs);
    };
    show();
  });
}
