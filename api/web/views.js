// Which view shows, the one poll that keeps it fresh, and re-rendering it.

const POLL_MS = 1500;

let pollTimer = null;
let router = async () => {};

export function showView(name) {
  for (const view of document.querySelectorAll(".view")) view.hidden = view.id !== `view-${name}`;
  for (const link of document.querySelectorAll("#nav a")) {
    link.classList.toggle("active", link.dataset.view === name ||
      (link.dataset.view === "jobs" && (name === "job" || name === "compare")));
  }
}

export function stopPolling() {
  clearTimeout(pollTimer);
  pollTimer = null;
}

export function poll(fn) {
  stopPolling();
  pollTimer = setTimeout(async () => {
    if (document.hidden) { poll(fn); return; } // a background tab waits; it catches up when shown
    try { await fn(); } catch (error) { if (error.status !== 401) console.warn(error); }
  }, POLL_MS);
}

/** The entry module hands its router here, so views can re-render without importing the entry
 * (which imports them). */
export function setRouter(route) { router = route; }

/** Show the view the address names, afresh (after a sign-out or a cancel). */
export function render() { return router(); }
