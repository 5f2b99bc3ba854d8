// The job list: every job the key may see, with progress bars that follow the running ones.

import { json, session } from "./api.js";
import { $, el, stateBadge, toast } from "./dom.js";
import { age, duration, jobDuration, jobName, scoresText, seconds } from "./format.js";
import { poll, render, showView } from "./views.js";

/** The states of a job that is not done yet (the API's ACTIVE). */
export const ACTIVE = new Set(["pricing", "queued", "running"]);
const PAGE_SIZE = 20;
/** The largest page GET /v1/jobs gives (its `limit`'s bound). */
export const MAX_PAGE_SIZE = 100;

/** How many jobs the list shows: "Show more" adds a page. */
let jobsLimit = PAGE_SIZE;
/** The list's filter (`#/jobs/tag/T/batch/B`): a tag (GET /v1/jobs?tag=), a batch (its jobs,
 * GET /v1/batches/{id}), or both (the batch's jobs with the tag). */
let filter = { tag: "", batch: "" };

/** The filter an address's arguments after `#/jobs` name. */
export function filterOf(args) {
  const found = { tag: "", batch: "" };
  for (let i = 0; i + 1 < args.length; i += 2) {
    if (args[i] in found) found[args[i]] = decodeURIComponent(args[i + 1]);
  }
  return found;
}

function filterHash(tag, batch) {
  const parts = ["#/jobs"];
  if (tag) parts.push("tag", encodeURIComponent(tag));
  if (batch) parts.push("batch", encodeURIComponent(batch));
  return parts.join("/");
}

/** A job's tags and batch as links that filter the list by them. */
function chips(job) {
  const links = (job.tags || []).map((tag) =>
    el("a", { class: "chip", href: filterHash(tag, ""), title: `jobs tagged ${tag}` }, tag));
  if (job.batch) {
    links.push(el("a", { class: "chip batch", href: filterHash("", job.batch), title: `batch ${job.batch}` },
      `batch ${job.batch.slice(0, 8)}`));
  }
  return links.length ? el("span", { class: "chips" }, links) : null;
}

/** The page of jobs the filter selects: `{items, total, next, batch}`. */
async function jobsPage() {
  if (filter.batch) {
    const batch = await json(`/v1/batches/${encodeURIComponent(filter.batch)}`);
    const items = batch.jobs.map((entry) => entry.job).filter(Boolean)
      .filter((job) => !filter.tag || job.tags.includes(filter.tag));
    return { items, total: items.length, next: null, batch };
  }
  const tag = filter.tag ? `&tag=${encodeURIComponent(filter.tag)}` : "";
  return json(`/v1/jobs?limit=${jobsLimit}${tag}`);
}

function batchSummary(batch) {
  if (!batch) return "";
  const states = Object.entries(batch.progress.by_state).map(([state, n]) => `${n} ${state}`).join(", ");
  return `Batch ${batch.id.slice(0, 8)} (${batch.tags.join(", ") || "no tags"}): ` +
    `${batch.progress.finished}/${batch.progress.total} finished · ${states}`;
}

function progressOf(job) {
  if (job.state === "succeeded") return { fraction: 1, text: "done" };
  const p = job.progress;
  if (job.state === "queued") return { fraction: 0, text: "waiting for a worker" };
  if (job.state === "pricing") {
    // the bar is the run's: pricing comes before it, its own share of levels priced is text
    const priced = p?.fraction == null ? "" : ` (${Math.round(p.fraction * 100)} % of the levels)`;
    return { fraction: 0, text: `pricing: ${p?.stage ?? "waiting for a pricing worker"}${priced}` };
  }
  if (!p) return { fraction: 0, text: "—" };
  if (!p.level || !p.bundles_total) {
    // the level is being prepared (a QPU solver's embedding search can take minutes)
    return { fraction: Math.max(0, p.level - 1) / Math.max(p.levels, 1),
      text: `level ${Math.max(p.level, 1)}/${p.levels || "?"}: ${p.phase || "preparing"}` };
  }
  return {
    fraction: Math.min(1, (p.level - 1 + p.bundles_done / p.bundles_total) / Math.max(p.levels, 1)),
    text: `level ${p.level}/${p.levels} · ${p.bundles_done}/${p.bundles_total} bundles`,
  };
}

export function progressBar(job) {
  if (job.state === "failed" || job.state === "cancelled") return el("span", { class: "muted" }, "—");
  const { fraction, text } = progressOf(job);
  const bar = el("span", { class: "bar-fill" });
  bar.style.width = `${Math.round(fraction * 100)}%`;
  return el("div", { class: `progress ${job.state}` },
    el("div", {
      class: "bar", role: "progressbar", "aria-valuemin": "0", "aria-valuemax": "100",
      "aria-valuenow": String(Math.round(fraction * 100)), "aria-label": `progress of ${job.id}`,
    }, bar),
    el("span", { class: "bar-text" }, text));
}

export async function cancelJob(id) {
  try {
    await json(`/v1/jobs/${id}`, { method: "DELETE" });
    toast(`job ${id.slice(0, 8)} cancelled`);
  } catch (error) {
    if (error.status !== 401) toast(error.message);
  }
  render();
}

async function refreshJobs() {
  const page = await jobsPage();
  const details = await Promise.all(page.items.map((job) =>
    ACTIVE.has(job.state) ? json(`/v1/jobs/${job.id}`).catch(() => job) : job));
  const rows = details.map((job) => el("tr", { "data-job": job.id },
    el("td", { "data-label": "Job", class: "job-name" },
      el("a", { href: `#/job/${job.id}`, title: job.id }, jobName(job)),
      el("span", { class: "job-id" }, job.id.slice(0, 8)), chips(job)),
    el("td", { class: "owner-col", "data-label": "User" }, job.owner ?? "—"),
    el("td", { "data-label": "State" }, stateBadge(job.state)),
    el("td", { "data-label": "Progress" }, progressBar(job)),
    el("td", { "data-label": "Solver" }, job.solver,
      el("span", { class: "sub" }, `${job.width}×${job.height}`)),
    el("td", { "data-label": "Duration", class: "nowrap" }, duration(jobDuration(job))),
    el("td", { "data-label": "RMSE · BPP", class: "scores" }, scoresText(job)),
    el("td", { "data-label": "QPU", class: "nowrap" }, job.qpu_seconds === null || job.qpu_seconds === undefined ? "—" : seconds(job.qpu_seconds)),
    el("td", { "data-label": "Age", class: "nowrap" }, el("time", { datetime: job.created_at }, age(job.created_at))),
    el("td", {}, ACTIVE.has(job.state)
      ? el("button", { type: "button", class: "small danger", onclick: () => cancelJob(job.id) }, "Cancel")
      : null)));
  $("#jobs-table tbody").replaceChildren(...rows);
  $("#jobs-table").hidden = !rows.length;
  const filtered = Boolean(filter.tag || filter.batch);
  $("#jobs-empty").hidden = Boolean(rows.length) || filtered;
  $("#jobs-none").hidden = Boolean(rows.length) || !filtered;
  $("#batch-summary").textContent = batchSummary(page.batch);
  $("#batch-summary").hidden = !page.batch;
  $("#jobs-count").textContent = page.total ? `${page.total} job${page.total === 1 ? "" : "s"}` +
    (session.me.admin ? " (everyone's)" : "") : "";
  $("#jobs-more").hidden = !page.next;
  if (!$("#view-jobs").hidden) poll(refreshJobs);
}

export async function showJobs(args = []) {
  showView("jobs");
  filter = filterOf(args);
  $("#filter-tag").value = filter.tag;
  $("#filter-batch").value = filter.batch;
  $("#filter-clear").hidden = !(filter.tag || filter.batch);
  await refreshJobs();
}

export function setUpJobList() {
  $("#jobs-filter").addEventListener("submit", (event) => {
    event.preventDefault();
    location.hash = filterHash($("#filter-tag").value.trim(), $("#filter-batch").value.trim());
  });
  $("#filter-clear").addEventListener("click", () => { location.hash = "#/jobs"; });
  $("#jobs-more").addEventListener("click", () => {
    jobsLimit = Math.min(MAX_PAGE_SIZE, jobsLimit + PAGE_SIZE);
    refreshJobs();
  });
}
