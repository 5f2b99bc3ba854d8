// Signing in and out: the key form, and a `#key=...` link (what `qhsm serve` prints), which
// never switches this tab to another account without asking.

import { forgetKey, session, signIn, storedKey, whoIs } from "./api.js";
import { $ } from "./dom.js";
import { userText } from "./format.js";
import { render, showView, stopPolling } from "./views.js";

export function signOut(message) {
  forgetKey();
  $("#signin-error").textContent = message || "";
  location.hash = "#/signin";
  render();
}

/** The key of a `#key=...` address (what `qhsm serve` prints), if this is one. */
export function fragmentKey() {
  const fragment = location.hash.match(/^#key=(.+)$/);
  return fragment ? decodeURIComponent(fragment[1]) : null;
}

/** Ask before a link's key signs this tab in: a link to `#key=<someone else's key>` must never
 * switch accounts silently (the uploads would go to that account). Resolves to the choice. */
function confirmSwitch(next) {
  return new Promise((resolve) => {
    stopPolling();
    $("#nav").hidden = true;
    $("#switch-to").textContent = userText(next);
    $("#switch-from").hidden = !session.me;
    if (session.me) $("#switch-current").textContent = userText(session.me);
    $("#switch-accept").textContent = `Sign in as ${next.name}`;
    $("#switch-decline").textContent = session.me ? `Stay ${session.me.name}` : "Cancel";
    showView("switch");
    const choose = (accepted) => () => {
      $("#switch-accept").onclick = $("#switch-decline").onclick = null;
      resolve(accepted);
    };
    $("#switch-accept").onclick = choose(true);
    $("#switch-decline").onclick = choose(false);
    $("#switch-accept").focus();
  });
}

/** Sign in with the tab's stored key, then consider the fragment's (what `qhsm serve` prints
 * when it makes a key): the page says whose it is and asks, unless it is the tab's own user.
 * The fragment never reaches the server (browsers do not send it) and is dropped from the
 * address bar at once. */
export async function signInFromFragment() {
  const fromFragment = fragmentKey();
  if (fromFragment) history.replaceState(null, "", `${location.pathname}#/jobs`);
  if (storedKey() && !session.me) {
    try {
      await signIn(storedKey());
    } catch {
      forgetKey();
    }
  }
  if (fromFragment && fromFragment !== storedKey()) {
    try {
      const next = await whoIs(fromFragment);
      const same = session.me && session.me.name === next.name;
      if (same || (await confirmSwitch(next))) await signIn(fromFragment);
    } catch (error) {
      $("#signin-error").textContent = error.message;
    }
  }
  render();
}

export function setUpSignIn() {
  $("#signin-form").addEventListener("submit", async (event) => {
    event.preventDefault();
    $("#signin-error").textContent = "";
    try {
      await signIn($("#key").value.trim());
      $("#key").value = "";
      if (location.hash === "#/signin" || !location.hash) location.hash = "#/jobs";
      render();
    } catch (error) {
      $("#signin-error").textContent = error.message;
    }
  });
  $("#sign-out").addEventListener("click", () => signOut(""));
}
