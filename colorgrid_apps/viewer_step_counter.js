// The export's step counter, over viser's playback clock (which reads seconds to a tenth, one step being
// STEP_SECONDS of them): the whole step the scene shows, read from the playback slider.
(() => {
  const stepSeconds = __STEP_SECONDS__, steps = __STEPS__;
  const counter = document.createElement("span");
  counter.id = "colorgrid-step";
  setInterval(() => {
    const clock = document.querySelector(".mantine-NumberInput-root");
    const slider = document.querySelector("[role=slider][aria-valuenow]");
    if (!clock || !slider) return;
    if (!counter.isConnected) document.body.append(counter);
    const box = clock.getBoundingClientRect();
    Object.assign(counter.style, { left: `${box.left}px`, top: `${box.top}px`, width: `${box.width}px`,
                                   height: `${box.height}px` });
    const step = Math.min(steps, Math.floor(Number(slider.getAttribute("aria-valuenow")) / stepSeconds + 1e-6));
    counter.textContent = String(step);
    counter.title = `step ${step} of ${steps}`;
  }, 50);
})();
