// QPU budgets: used, reserved and left in the budget's period (when it resets), and the QPU time
// of each job (admins see every user).

import { download, json, session } from "./api.js";
import { $, el, keyValues } from "./dom.js";
import { seconds } from "./format.js";
import { showView } from "./views.js";

function budgetBar(entry) {
  const limit = entry.limit_seconds;
  if (limit === null) return null; // unlimited: nothing to fill
  const used = el("span", { class: "bar-fill" });
  const reserved = el("span", { class: "bar-fill reserved" });
  if (limit) {
    used.style.width = `${Math.min(100, (100 * entry.used_seconds) / limit)}%`;
    reserved.style.width = `${Math.min(100, (100 * entry.reserved_seconds) / limit)}%`;
  }
  return el("div", { class: "bar budget", "aria-label": `budget of ${entry.user}` }, used, reserved);
}

export async function showUsage() {
  showView("usage");
  const usage = await json("/v1/usage");
  const cards = usage.users.map((entry) => el("div", { class: "card usage-card", "data-user": entry.user },
    el("h2", {}, entry.user),
    entry.warning ? el("p", { class: "field-error", role: "alert" }, entry.warning) : null,
    budgetBar(entry),
    keyValues([["used", seconds(entry.used_seconds)], ["reserved", seconds(entry.reserved_seconds)],
      ["left", entry.remaining_seconds === null ? "unlimited" : seconds(entry.remaining_seconds)],
      ["budget", entry.limit_seconds === null ? "unlimited" : seconds(entry.limit_seconds)],
      ["period", entry.period + (entry.period_start ? ` since ${entry.period_start.slice(0, 10)}` : "")],
      ["resets", entry.resets_at ? new Date(entry.resets_at).toISOString().replace(".000Z", " UTC").replace("T", " ") : "never"],
      ["used in total", seconds(entry.total_used_seconds)]]),
    entry.jobs.length
      ? el("table", { class: "small-table" }, el("thead", {}, el("tr", {}, el("th", {}, "Job"), el("th", {}, "QPU time"), el("th", {}, "Problems"))),
        el("tbody", {}, entry.jobs.map((job) => el("tr", {},
          el("td", {}, el("a", { href: `#/job/${job.id}` }, job.id.slice(0, 8))),
          el("td", {}, seconds(job.qpu_seconds)), el("td", {}, job.problems)))))
      : el("p", { class: "muted" }, "No QPU time charged yet.")));
  $("#view-usage").replaceChildren(
    el("h1", {}, "QPU usage"),
    el("p", { class: "muted" }, `QPU access time (hybrid: charge time) charged to ${session.me.admin ? "every user" : "you"}; ` +
      `total ${seconds(usage.total_used_seconds)}` + (usage.qpu_in_flight === null || usage.qpu_in_flight === undefined ? "" : `, ${usage.qpu_in_flight} problem(s) in flight lab-wide`)),
    el("button", { type: "button", class: "small", onclick: () => download("/v1/usage?format=csv", "qpu-usage.csv") }, "Export CSV"),
    el("div", { class: "cards" }, cards));
}
