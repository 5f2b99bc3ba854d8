// One job's page: its facts, progress, result images, metrics, levels and solver usage; it
// follows the job while it runs.

import { authImage, download, json } from "./api.js";
import { $, el, keyValues, stateBadge } from "./dom.js";
import { age, duration, fmt, groundTruthText, jobDuration, jobName, rangeText, seconds } from "./format.js";
import { ACTIVE, cancelJob, MAX_PAGE_SIZE, progressBar } from "./jobs.js";
import { poll, showView } from "./views.js";

/** What "repaired" counts (the API's LevelTiming.repaired says the same). */
const REPAIRED_NOTE = "Repaired: pixels whose QUBO sample was not a valid label encoding " +
  "(one-hot: no bit or several bits set; domain-wall: a broken wall) and that were given their " +
  "cheapest label next to their valid neighbours, with their share of the level's pixels. A " +
  "high share means the solver's samples are far from valid: its chain strength or read count " +
  "is too low for these bundles. The exact row solver never needs a repair.";

export function colourBar(bar, label) {
  const top = bar.scale;
  const ticks = [0, top / 2, top].map((value) => el("span", {}, `${fmt(value)} px`));
  bar.img.className = "colourbar-img";
  return el("figure", { class: "colourbar" }, bar.img, el("div", { class: "ticks" }, ticks),
    el("figcaption", {}, label));
}

export async function resultImages(job, { withLeft = true } = {}) {
  const base = `/v1/jobs/${job.id}`;
  const [left, disparity, bar] = await Promise.all([
    withLeft ? authImage(`${base}/left.png`, "Left view").catch(() => null) : null,
    authImage(`${base}/preview.png`, "Disparity"),
    authImage(`${base}/colorbar.png?map=disparity`, "Disparity colour scale"),
  ]);
  const figures = [];
  if (left) figures.push(el("figure", { class: "shot" }, left.img, el("figcaption", {}, "Left view")));
  figures.push(el("figure", { class: "shot" }, disparity.img,
    colourBar(bar, "disparity (near = warm)")));
  if (job.metrics) {
    const [errors, errorBar] = await Promise.all([
      authImage(`${base}/error.png`, "Error map").catch(() => null),
      authImage(`${base}/colorbar.png?map=error`, "Error colour scale"),
    ]);
    if (errors) {
      figures.push(el("figure", { class: "shot" }, errors.img,
        colourBar(errorBar, "|disparity − ground truth| (grey: not evaluated)")));
    }
  }
  return el("div", { class: "shots" }, figures);
}

export function metricsBlock(job) {
  if (!job.metrics) return null;
  // fixed decimals: an RMSE of 1.002 px must not read "1 px"
  const metric = (value, name) => el("div", { class: "metric" },
    el("span", { class: "metric-value" }, value), el("span", { class: "metric-name" }, name));
  // Middlebury's and KITTI's measures (null for jobs from before they were kept)
  const measure = (key, name, unit, digits) => (job.metrics[key] == null ? null
    : metric(`${job.metrics[key].toFixed(digits)} ${unit}`, name));
  return el("div", { class: "metrics", "aria-label": "metrics" },
    metric(`${job.metrics.rmse.toFixed(3)} px`, "RMSE"),
    metric(`${job.metrics.bpp.toFixed(2)} %`, "bad pixels (> 1 px)"),
    measure("avgerr", "avgerr", "px", 3),
    measure("bad_2", "bad-2 (> 2 px)", "%", 2),
    measure("d1", "KITTI D1 (> 3 px and > 5 %)", "%", 2),
    metric(String(job.metrics.pixels), "pixels evaluated"));
}

function levelsTable(job) {
  if (!job.levels.length) return null;
  const timingNames = [...new Set(job.levels.flatMap((level) => Object.keys(level.timing || {})))];
  const sent = job.levels.some((level) => level.info?.bundles_sent !== undefined);
  const headings = ["Level", "Size", "Candidates", "Bundles", ...(sent ? ["Sent to solver"] : []), "Energy", "Repaired", "Time",
    "Solver time", ...timingNames.map((name) => name.replaceAll("_", " "))];
  const timing = (level, name) => {
    const value = level.timing?.[name];
    return name.includes("time") ? seconds(value) : fmt(value);
  };
  const repaired = (level) => {
    const pixels = level.views * level.width * level.height;
    if (!level.repaired || !pixels) return String(level.repaired);
    return `${level.repaired} (${fmt((100 * level.repaired) / pixels, 2)} %)`;
  };
  const row = (level) => el("tr", {},
    el("td", {}, level.downsample > 1 ? `${level.index + 1} (1/${level.downsample})` : level.index + 1),
    el("td", {}, `${level.width}×${level.height}${level.views > 1 ? ` ×${level.views} views` : ""}`),
    el("td", {}, level.candidates),
    el("td", {}, level.bundles),
    sent ? el("td", { title: "the other bundles were solved classically (tile certificates, roof duality), charged nothing" },
      level.info?.bundles_sent === undefined ? "—"
        : `${level.info.bundles_sent} (${fmt((100 * level.info.variables_sent) / Math.max(level.info.variables, 1), 1)} % of the variables)`) : null,
    el("td", {}, fmt(level.energy, 5)),
    el("td", { class: "repaired" }, repaired(level)),
    el("td", {}, seconds(level.seconds)),
    el("td", {}, seconds(level.solver_seconds)),
    timingNames.map((name) => el("td", {}, timing(level, name))));
  const table = el("table", { class: "levels" },
    el("thead", {}, el("tr", {}, headings.map((name) =>
      el("th", name === "Repaired" ? { title: REPAIRED_NOTE, "aria-describedby": "repaired-note" } : {}, name)))),
    el("tbody", {}, job.levels.map(row)));
  return el("div", {},
    el("div", { class: "table-card" }, table),
    el("p", { class: "hint", id: "repaired-note" }, REPAIRED_NOTE));
}

function usageList(usage) {
  return keyValues(Object.entries(usage || {}).map(([name, value]) =>
    [name.replaceAll("_", " "), name.includes("time") || name.includes("seconds") ? seconds(value) : fmt(value)]));
}

async function compareChooser(job) {
  const page = await json(`/v1/jobs?limit=${MAX_PAGE_SIZE}`);
  const others = page.items.filter((other) => other.id !== job.id && other.state === "succeeded" &&
    other.width === job.width && other.height === job.height);
  if (!others.length) return el("p", { class: "muted" }, "Compare: no other finished job of this size yet.");
  const select = el("select", { id: "compare-with" }, others.map((other) =>
    el("option", { value: other.id }, `${jobName(other)} · ${other.solver} · ${age(other.created_at)}`)));
  return el("div", { class: "compare-pick" }, el("label", { for: "compare-with" }, "Compare with"), select,
    el("button", { type: "button", class: "small", onclick: () => { location.hash = `#/compare/${job.id}/${select.value}`; } }, "Compare"));
}

// The ids SAPI gave the job's D-Wave problems: what finds them on Leap (each is labelled
// "qhsm job <id> level <n> bundle <first> #k" there too).
function problemsBlock(job) {
  const ids = job.problem_ids || [];
  if (!ids.length) return null;
  return el("details", { class: "params-box" },
    el("summary", {}, `D-Wave problems (${ids.length}): ids on Leap`),
    el("pre", { class: "problem-ids", "aria-label": "D-Wave problem ids" }, ids.join("\n")));
}

function warningsBlock(job) {
  if (!job.warnings?.length) return null;
  return el("div", { class: "card notice warnings", role: "status", "aria-label": "warnings" },
    job.warnings.map((text) => el("p", {}, text)));
}

/** Pin the job (kept past the retention) or unpin it, then show it again. */
async function togglePin(job) {
  await json(`/v1/jobs/${job.id}/pin`, { method: job.pinned ? "DELETE" : "POST" });
  await showJob(job.id);
}

/** The provenance map (which stage decided each pixel) with its legend, from the API's one
 * legend, each stage's pixels and share; null when the job has no such map. */
async function provenanceFigure(job) {
  if (!job.links?.provenance) return null;
  const [map, legend] = await Promise.all([
    authImage(job.links.provenance, "Provenance map").catch(() => null),
    json("/v1/provenance-legend").catch(() => []),
  ]);
  if (!map) return null;
  const counts = job.provenance_counts || {};
  const total = Object.values(counts).reduce((sum, n) => sum + n, 0) || 1;
  const swatch = (colour) => {  // CSSOM, not a style attribute: the page's CSP allows no inline style
    const span = el("span", { class: "swatch" });
    span.style.backgroundColor = colour;
    return span;
  };
  const rows = legend.map((entry) => el("li", { title: entry.meaning, "data-stage": entry.name },
    swatch(entry.colour),
    `${entry.code} ${entry.name.replaceAll("_", " ")}: ${fmt(counts[entry.name] ?? 0)} px ` +
    `(${(100 * (counts[entry.name] ?? 0) / total).toFixed(2)} %)`));
  return el("figure", { class: "shot provenance" }, map.img,
    el("figcaption", {}, "Provenance: which stage decided each pixel (hover a stage for what it means)"),
    el("ul", { class: "legend", "aria-label": "provenance legend" }, rows));
}

/** Buttons for the maps beside the disparity and, with cameras, its depth and point cloud:
 * those the job's links name. */
function extraDownloads(job) {
  const files = [["validity", "validity PNG", `${job.id}.valid.png`],
    ["confidence", "confidence PFM", `${job.id}.confidence.pfm`],
    ["provenance", "provenance PNG", `${job.id}.provenance.png`],
    ["depth", "depth PFM", `${job.id}.depth.pfm`], ["points", "point cloud PLY", `${job.id}.ply`]];
  return files.filter(([link]) => job.links?.[link]).map(([link, label, name]) =>
    el("button", { type: "button", class: "small", "data-download": link, onclick: () => download(job.links[link], name) }, label));
}

export async function showJob(id) {
  showView("job");
  const view = $("#view-job");
  const job = await json(`/v1/jobs/${id}`).catch((error) => {
    if (error.status === 404) {
      view.replaceChildren(el("h1", {}, "Job not found"), el("p", { class: "field-error", role: "alert" }, error.message));
      return null;
    }
    throw error;
  });
  if (!job) return;
  const active = ACTIVE.has(job.state);
  const facts = [["id", job.id], ["files", job.files?.length ? job.files.join(" · ") : "—"],
    ["solver", job.solver], ["size", `${job.width}×${job.height}`],
    ["disparity range", rangeText(job.disparity_range)], ["ground truth", groundTruthText(job)],
    ["user", job.owner ?? "—"], ["submitted", `${new Date(job.created_at).toLocaleString()} (${age(job.created_at)})`],
    ["finished", job.finished_at ? new Date(job.finished_at).toLocaleString() : "—"],
    ["duration", duration(jobDuration(job))]];
  if (job.qpu_seconds !== null && job.qpu_seconds !== undefined) facts.push(["QPU time charged", seconds(job.qpu_seconds)]);
  if (job.expires_at) facts.push(["deleted on", new Date(job.expires_at).toLocaleString()]);
  if (job.pinned) facts.push(["deleted on", "never: pinned"]);
  if (job.version) facts.push(["qhsm version", job.version]);
  if (job.tags?.length) facts.push(["tags", job.tags.join(", ")]);
  const parts = [
    el("div", { class: "title-row" },
      el("h1", {}, job.label || `Job ${job.id.slice(0, 8)}`), stateBadge(job.state),
      active ? el("button", { type: "button", class: "small danger", onclick: () => cancelJob(job.id) }, "Cancel") : null,
      el("button", { type: "button", class: "small", onclick: () => togglePin(job) }, job.pinned ? "Unpin" : "Pin"),
      el("button", { type: "button", class: "small", onclick: () => download(`/v1/jobs/${job.id}/export`, `${job.id}.zip`) }, "Export")),
    warningsBlock(job),
    keyValues(facts),
  ];
  if (active || job.state === "succeeded") parts.push(progressBar(job));
  if (job.error) parts.push(el("p", { class: "field-error", role: "alert" }, job.error));
  if (job.state === "succeeded") {
    parts.push(metricsBlock(job));
    const images = await resultImages(job);
    const provenance = await provenanceFigure(job);
    if (provenance) images.append(provenance);
    parts.push(images);
    parts.push(el("div", { class: "downloads" }, el("span", {}, "Download:"),
      [["pfm", "PFM"], ["png", "16-bit PNG"], ["npy", "NPY"]].map(([format, label]) =>
        el("button", { type: "button", class: "small", onclick: () => download(`/v1/jobs/${job.id}/disparity?format=${format}`, `${job.id}.${format}`) }, label)),
      extraDownloads(job)));
    parts.push(await compareChooser(job));
  }
  parts.push(el("h2", {}, "Levels"), levelsTable(job) ?? el("p", { class: "muted" }, "No level finished yet."));
  parts.push(el("h2", {}, "Solver usage"), usageList(job.usage), problemsBlock(job));
  parts.push(el("details", { class: "params-box" }, el("summary", {}, "Parameters (JSON)"),
    el("pre", { class: "params" }, JSON.stringify(job.config, null, 2))));
  view.replaceChildren(...parts.filter(Boolean));
  if (active) poll(() => showJob(id));
}
