// qhsm lab page: a small client of the /v1 API, as native ES modules (no framework, no build
// step, nothing loaded from elsewhere). This entry routes the address to a view and wires the
// page's controls; each module below does one part of the page.

import { onUnauthorized, releaseImages, session } from "./api.js";
import { showCompare } from "./compare.js";
import { $, addErrorSlots, toast } from "./dom.js";
import { setUpSubmitForm, showSubmit } from "./form.js";
import { userText } from "./format.js";
import { showJob } from "./job.js";
import { setUpJobList, showJobs } from "./jobs.js";
import { fragmentKey, setUpSignIn, signInFromFragment, signOut } from "./signin.js";
import { showUsage } from "./usage.js";
import { setUpUserForm, showUsers } from "./users.js";
import { setRouter, showView, stopPolling } from "./views.js";

/** Show the view `#/view/args...` names, or the sign-in view when signed out. */
async function route() {
  stopPolling();
  const signedIn = Boolean(session.me);
  $("#nav").hidden = !signedIn;
  $("#who").hidden = !signedIn;
  if (!signedIn) {
    showView("signin");
    $("#key").focus();
    return;
  }
  $("#who-name").textContent = userText(session.me);
  $("#nav-users").hidden = !session.me.admin;
  document.body.classList.toggle("admin", session.me.admin);
  const [, view = "jobs", ...args] = location.hash.split("/");
  try {
    if (view === "submit") await showSubmit();
    else if (view === "job" && args[0]) { releaseImages(); await showJob(args[0]); }
    else if (view === "compare" && args[1]) { releaseImages(); await showCompare(args[0], args[1]); }
    else if (view === "usage") await showUsage();
    else if (view === "users" && session.me.admin) await showUsers();
    else await showJobs(view === "jobs" ? args : []);
  } catch (error) {
    if (error.status !== 401) toast(error.message);
  }
}

setRouter(route);
onUnauthorized(signOut);
addErrorSlots();
setUpSignIn();
setUpSubmitForm();
setUpJobList();
setUpUserForm();
window.addEventListener("hashchange", () => (fragmentKey() ? signInFromFragment() : route()));
signInFromFragment();
