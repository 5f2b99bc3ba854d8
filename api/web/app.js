// qhsm lab page: a small client of the /v1 API. No framework, no build step, nothing loaded from
// elsewhere. The API key lives in this tab's sessionStorage and goes out as a Bearer header.
"use strict";

const KEY_STORAGE = "qhsm.key";
const POLL_MS = 1500;
const ACTIVE = new Set(["queued", "running"]);
const FIELD_NAMES = ["left", "right", "preset", "solver", "encoding", "max_disparity",
  "solver_params", "ground_truth", "gt_scale", "gt_border", "label"];

const state = { me: null, schema: null, solvers: null, timer: null, urls: [], jobsLimit: 20 };

// --- helpers ---------------------------------------------------------------------------------

const $ = (selector, root = document) => root.querySelector(selector);

function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [name, value] of Object.entries(attrs)) {
    if (value === null || value === undefined || value === false) continue;
    if (name === "class") node.className = value;
    else if (name.startsWith("on")) node.addEventListener(name.slice(2), value);
    else node.setAttribute(name, value === true ? "" : value);
  }
  for (const child of children.flat()) {
    if (child === null || child === undefined || child === false) continue;
    node.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
  return node;
}

function fmt(value, digits = 3) {
  if (value === null || value === undefined) return "—";
  if (typeof value !== "number") return String(value);
  if (Number.isInteger(value)) return String(value);
  return value.toPrecision(digits).replace(/\.?0+(e|$)/, "$1");
}

function seconds(value) {
  if (value === null || value === undefined) return "—";
  if (value < 1e-3 && value > 0) return `${fmt(value * 1e6)} µs`;
  if (value < 1) return `${fmt(value * 1e3)} ms`;
  return `${fmt(value)} s`;
}

/** A duration in seconds as people read it: 0.8 s, 12.3 s, 3 min 08 s, 1 h 02 min. */
function duration(value) {
  if (value === null || value === undefined || !Number.isFinite(value)) return "—";
  if (value < 60) return `${value < 10 ? value.toFixed(1) : Math.round(value)} s`;
  const minutes = Math.floor(value / 60);
  if (minutes < 60) return `${minutes} min ${String(Math.round(value % 60)).padStart(2, "0")} s`;
  return `${Math.floor(minutes / 60)} h ${String(minutes % 60).padStart(2, "0")} min`;
}

/** How long a job ran: started to finished, or to now while it runs. */
function jobDuration(job) {
  if (!job.started_at) return null;
  const end = job.finished_at ? Date.parse(job.finished_at) : Date.now();
  return Math.max(0, (end - Date.parse(job.started_at)) / 1000);
}

/** What a job is called: its label, else its files' names, else its short id. */
function jobName(job) {
  if (job.label) return job.label;
  if (job.files?.length) return job.files.join(" · ");
  return job.id.slice(0, 8);
}

function scoresText(job) {
  if (!job.metrics) return "—";
  const { rmse, bpp } = job.metrics;
  return `${rmse === null ? "n/a" : rmse.toFixed(3)} px · ${bpp === null ? "n/a" : bpp.toFixed(2)} %`;
}

function age(iso) {
  const delta = Math.max(0, (Date.now() - Date.parse(iso)) / 1000);
  if (delta < 60) return `${Math.round(delta)} s ago`;
  if (delta < 3600) return `${Math.round(delta / 60)} min ago`;
  if (delta < 86400) return `${Math.round(delta / 3600)} h ago`;
  return `${Math.round(delta / 86400)} d ago`;
}

function toast(message) {
  const box = $("#toast");
  box.textContent = message;
  box.hidden = false;
  clearTimeout(toast.timer);
  toast.timer = setTimeout(() => { box.hidden = true; }, 4000);
}

class ApiError extends Error {
  constructor(status, detail) {
    super(typeof detail === "string" ? detail : JSON.stringify(detail));
    this.status = status;
    this.detail = detail;
  }
}

function key() { return sessionStorage.getItem(KEY_STORAGE); }

async function api(path, options = {}) {
  const headers = new Headers(options.headers || {});
  if (key()) headers.set("Authorization", `Bearer ${key()}`);
  const response = await fetch(path, { ...options, headers });
  if (response.status === 401 && options.signIn !== true) {
    signOut((await body(response)).detail);
    throw new ApiError(401, "signed out");
  }
  if (!response.ok) {
    const data = await body(response);
    throw new ApiError(response.status, data.detail ?? `HTTP ${response.status}`);
  }
  return response;
}

async function body(response) {
  try { return await response.json(); } catch { return {}; }
}

async function json(path, options) { return (await api(path, options)).json(); }

async function send(path, method, payload) {
  return json(path, {
    method, headers: { "Content-Type": "application/json" },
    body: payload === undefined ? undefined : JSON.stringify(payload),
  });
}

/** An <img> whose bytes are fetched with the key (an <img src> cannot send headers). */
async function authImage(path, alt) {
  const response = await api(path);
  const url = URL.createObjectURL(await response.blob());
  state.urls.push(url);
  return { img: el("img", { src: url, alt }), scale: Number(response.headers.get("X-Scale-Max")) };
}

async function download(path, filename) {
  const response = await api(path);
  const url = URL.createObjectURL(await response.blob());
  const link = el("a", { href: url, download: filename });
  document.body.append(link);
  link.click();
  link.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
}

// --- sign in ---------------------------------------------------------------------------------

async function signIn(candidate) {
  const response = await fetch("/v1/me", { headers: { Authorization: `Bearer ${candidate}` } });
  if (!response.ok) {
    const data = await body(response);
    throw new ApiError(response.status, data.detail ?? `HTTP ${response.status}`);
  }
  sessionStorage.setItem(KEY_STORAGE, candidate);
  state.me = await response.json();
}

function signOut(message) {
  sessionStorage.removeItem(KEY_STORAGE);
  state.me = null;
  $("#signin-error").textContent = message || "";
  location.hash = "#/signin";
  render();
}

// --- routing ---------------------------------------------------------------------------------

function showView(name) {
  for (const view of document.querySelectorAll(".view")) view.hidden = view.id !== `view-${name}`;
  for (const link of document.querySelectorAll("#nav a")) {
    link.classList.toggle("active", link.dataset.view === name ||
      (link.dataset.view === "jobs" && (name === "job" || name === "compare")));
  }
}

function stopPolling() {
  clearTimeout(state.timer);
  state.timer = null;
}

function poll(fn) {
  stopPolling();
  state.timer = setTimeout(async () => {
    if (document.hidden) { poll(fn); return; } // a background tab waits; it catches up when shown
    try { await fn(); } catch (error) { if (error.status !== 401) console.warn(error); }
  }, POLL_MS);
}

function releaseImages() {
  for (const url of state.urls) URL.revokeObjectURL(url);
  state.urls = [];
}

async function render() {
  stopPolling();
  const signedIn = Boolean(state.me);
  $("#nav").hidden = !signedIn;
  $("#who").hidden = !signedIn;
  if (!signedIn) {
    showView("signin");
    $("#key").focus();
    return;
  }
  $("#who-name").textContent = `${state.me.name}${state.me.admin ? " (admin)" : ""}`;
  $("#nav-users").hidden = !state.me.admin;
  document.body.classList.toggle("admin", state.me.admin);
  const [, view = "jobs", ...args] = location.hash.split("/");
  try {
    if (view === "submit") await showSubmit();
    else if (view === "job" && args[0]) { releaseImages(); await showJob(args[0]); }
    else if (view === "compare" && args[1]) { releaseImages(); await showCompare(args[0], args[1]); }
    else if (view === "usage") await showUsage();
    else if (view === "users" && state.me.admin) await showUsers();
    else { showView("jobs"); await refreshJobs(); }
  } catch (error) {
    if (error.status !== 401) toast(error.message);
  }
}

// --- submit ----------------------------------------------------------------------------------

/** MatchConfig's JSON schema from /openapi.json: which presets and encodings this server has. */
async function matchSchema() {
  if (!state.schema) {
    const openapi = await (await fetch("/openapi.json")).json();
    state.schema = openapi.components.schemas;
  }
  return state.schema;
}

function enumOf(schemas, name) {
  return schemas[name]?.enum ?? [];
}

function showSubmit() {
  showView("submit");
  state.submitReady = loadSubmitChoices();
  return state.submitReady;
}

async function loadSubmitChoices() {
  const schemas = await matchSchema();
  const config = schemas.MatchConfig?.properties ?? {};
  const preset = $("#preset");
  if (!preset.options.length) {
    const presets = enumOf(schemas, "Preset");
    const fallback = presets.length ? presets : ["paper"];
    const chosen = config.preset?.default ?? fallback[0];
    for (const name of fallback) {
      preset.append(el("option", { value: name, selected: name === chosen }, name));
    }
    preset.dataset.default = chosen;
    preset.disabled = !presets.length;
    const top = config.max_disparity?.default;
    $("#max-disparity").placeholder = top === undefined || top === "auto" ? "auto" : `default: ${top}`;
    const encoding = $("#encoding");
    encoding.append(el("option", { value: "" }, presets.length ? "default (from preset)" : "default"));
    for (const name of enumOf(schemas, "Encoding")) encoding.append(el("option", { value: name }, name));
  }
  const solvers = await json("/v1/solvers");
  const select = $("#solver");
  const previous = select.value || "exact";
  select.replaceChildren(...solvers.map((s) => el("option", {
    value: s.name, disabled: !s.available, selected: s.name === previous,
    title: s.available ? s.description : s.reason,
  }, s.available ? `${s.name}${s.offline ? " (offline)" : ""}` : `${s.name} — unavailable: ${s.reason}`)));
  state.solvers = Object.fromEntries(solvers.map((s) => [s.name, s]));
  describeSolver();
}

function describeSolver() {
  const info = state.solvers?.[$("#solver").value];
  $("#solver-note").textContent = info
    ? `${info.description}${info.uses_qpu_time ? " · uses QPU time from your budget" : ""}`
    : "";
}

function clearErrors(form) {
  for (const node of form.querySelectorAll(".field-error")) node.textContent = "";
  for (const node of form.querySelectorAll("[aria-invalid]")) node.removeAttribute("aria-invalid");
}

function showFieldError(form, field, message) {
  if (!/^[a-z_]+$/.test(field)) field = "form"; // names come from the API: keep selectors safe
  const slot = form.querySelector(`.field-error[data-field="${field}"]`) ||
    form.querySelector('.field-error[data-field="form"]');
  slot.textContent = slot.textContent ? `${slot.textContent} ${message}` : message;
  const input = form.querySelector(`[name="${field}"]`);
  if (input) {
    input.setAttribute("aria-invalid", "true");
    input.closest("details")?.setAttribute("open", "");
  }
}

/** Which form field an API error is about: FastAPI's loc, or the field the message starts with. */
function fieldOfError(detail) {
  if (Array.isArray(detail)) {
    return detail.map((item) => [String(item.loc?.at(-1) ?? "form"), item.msg]);
  }
  const text = String(detail);
  const param = text.match(/^params: ([a-z_]+)/);
  if (param && FIELD_NAMES.includes(param[1])) return [[param[1], text]];
  if (/^params: unknown solver/.test(text)) return [["solver", text]];
  if (param) return [["solver_params", text]];
  if (/^solver /.test(text)) return [["solver", text]];
  if (/ but right is /.test(text)) return [["right", text]];
  const form = text.match(/^(gt_scale|gt_border|label)\b/);
  if (form) return [[form[1], text]];
  const file = text.match(/^(left|right|ground_truth)\b/);
  if (file) return [[file[1], text]];
  if (/QPU|budget/i.test(text)) return [["solver", text]];
  return [["form", text]];
}

/** The form as the API's multipart body (null, with the fields' errors shown, when invalid). */
async function jobRequest(form) {
  clearErrors(form);
  await state.submitReady;
  const left = $("#left").files[0];
  const right = $("#right").files[0];
  let invalid = false;
  if (!left) { showFieldError(form, "left", "Choose the left image."); invalid = true; }
  if (!right) { showFieldError(form, "right", "Choose the right image."); invalid = true; }
  const params = { solver: $("#solver").value };
  const preset = $("#preset");
  if (!preset.disabled && preset.value !== preset.dataset.default) params.preset = preset.value;
  if ($("#encoding").value) params.encoding = $("#encoding").value;
  const maxDisparity = $("#max-disparity").value.trim();
  if (maxDisparity) params.max_disparity = Number(maxDisparity);
  const advanced = $("#solver-params").value.trim();
  if (advanced) {
    try {
      params.solver_params = JSON.parse(advanced);
    } catch (error) {
      showFieldError(form, "solver_params", `Not valid JSON: ${error.message}`);
      invalid = true;
    }
  }
  if (invalid) return null;
  const data = new FormData();
  data.append("left", left);
  data.append("right", right);
  data.append("params", JSON.stringify(params));
  const label = $("#label").value.trim();
  if (label) data.append("label", label);
  const truth = $("#ground-truth").files[0];
  if (truth) {
    data.append("ground_truth", truth);
    const scale = $("#gt-scale").value.trim();
    if (scale) data.append("gt_scale", scale); // empty: the service infers it, and says so
    data.append("gt_border", $("#gt-border").value || "0");
  }
  return data;
}

/** Before submitting: the QPU (hybrid) seconds the job would be charged and the share of its
 * bundles solved classically: tile certificates, roof duality (POST /v1/estimate). */
async function estimateJob() {
  const form = $("#submit-form");
  const out = $("#estimate-result");
  const data = await jobRequest(form);
  if (!data) return;
  for (const name of ["ground_truth", "gt_scale", "gt_border", "label"]) data.delete(name);
  out.textContent = "Estimating…";
  try {
    const e = await json("/v1/estimate", { method: "POST", body: data });
    out.textContent = !e.metered ? `${e.solver} is not metered: no QPU time is charged.`
      : `${seconds(e.seconds)} of ${e.levels[0]?.qubits_per_bundle === null ? "hybrid" : "QPU"} time; ` +
        `${fmt(100 * e.classical_share, 2)} % of ${e.bundles} bundles solved classically (tile certificates, roof duality); ` +
        (e.fits ? "fits your budget." : "does NOT fit your budget.");
  } catch (error) {
    out.textContent = "";
    if (error.status !== 401) {
      for (const [field, message] of fieldOfError(error.detail)) showFieldError(form, field, message);
    }
  }
}

async function submitJob(event) {
  event.preventDefault();
  const form = event.currentTarget;
  const data = await jobRequest(form);
  if (!data) return;
  const button = $("#submit-button");
  button.disabled = true;
  try {
    const job = await json("/v1/jobs", { method: "POST", body: data });
    location.hash = `#/job/${job.id}`;
  } catch (error) {
    if (error.status !== 401) {
      for (const [field, message] of fieldOfError(error.detail)) showFieldError(form, field, message);
    }
  } finally {
    button.disabled = false;
  }
}

/** A chosen file's preview, made by the API as PNG (browsers show neither Middlebury's PPM/PGM
 * nor PFM or TIFF); a file it cannot read gets its message instead. */
async function showThumbnail(zone, file) {
  const thumb = $(".thumb", zone);
  const error = $(".field-error", zone);
  thumb.hidden = true;
  error.textContent = "";
  if (!file) return;
  const data = new FormData();
  data.append("image", file);
  try {
    const response = await api("/v1/thumbnail", { method: "POST", body: data });
    if (thumb.src) URL.revokeObjectURL(thumb.src);
    thumb.src = URL.createObjectURL(await response.blob());
    thumb.alt = `chosen ${zone.dataset.input} file: ${file.name}`;
    thumb.hidden = false;
  } catch (failure) {
    if (failure.status !== 401) error.textContent = failure.message.replace(/^image\b/, file.name);
  }
}

function setUpDropZones() {
  for (const zone of document.querySelectorAll(".drop")) {
    const input = $(`#${zone.dataset.input}`);
    const show = () => showThumbnail(zone, input.files[0]);
    input.addEventListener("change", show);
    zone.addEventListener("dragover", (event) => { event.preventDefault(); zone.classList.add("over"); });
    zone.addEventListener("dragleave", () => zone.classList.remove("over"));
    zone.addEventListener("drop", (event) => {
      event.preventDefault();
      zone.classList.remove("over");
      if (event.dataTransfer.files.length) {
        input.files = event.dataTransfer.files;
        show();
      }
    });
  }
}

// --- jobs ------------------------------------------------------------------------------------

function progressOf(job) {
  if (job.state === "succeeded") return { fraction: 1, text: "done" };
  const p = job.progress;
  if (job.state === "queued") return { fraction: 0, text: "waiting for a worker" };
  if (!p) return { fraction: 0, text: "—" };
  if (!p.level || !p.bundles_total) {
    // the level is being prepared (a QPU solver's embedding search can take minutes)
    return { fraction: Math.max(0, p.level - 1) / Math.max(p.levels, 1),
      text: `preparing level ${Math.max(p.level, 1)}/${p.levels || "?"}` };
  }
  const within = p.bundles_total ? p.bundles_done / p.bundles_total : 0;
  return {
    fraction: Math.min(1, (p.level - 1 + within) / Math.max(p.levels, 1)),
    text: `level ${p.level}/${p.levels} · ${p.bundles_done}/${p.bundles_total} bundles`,
  };
}

function progressBar(job) {
  if (job.state === "failed" || job.state === "cancelled") return el("span", { class: "muted" }, "—");
  const { fraction, text } = progressOf(job);
  const bar = el("span", { class: "bar-fill" });
  bar.style.width = `${Math.round(fraction * 100)}%`;
  return el("div", { class: `progress ${job.state}` },
    el("div", {
      class: "bar", role: "progressbar", "aria-valuemin": "0", "aria-valuemax": "100",
      "aria-valuenow": String(Math.round(fraction * 100)), "aria-label": `progress of ${job.id}`,
    }, bar),
    el("span", { class: "bar-text" }, ACTIVE.has(job.state) || job.state === "succeeded" ? text : ""));
}

function stateBadge(value) { return el("span", { class: `badge ${value}` }, value); }

async function cancelJob(id) {
  try {
    await json(`/v1/jobs/${id}`, { method: "DELETE" });
    toast(`job ${id.slice(0, 8)} cancelled`);
  } catch (error) {
    if (error.status !== 401) toast(error.message);
  }
  render();
}

async function refreshJobs() {
  const page = await json(`/v1/jobs?limit=${state.jobsLimit}`);
  const details = await Promise.all(page.items.map((job) =>
    ACTIVE.has(job.state) ? json(`/v1/jobs/${job.id}`).catch(() => job) : job));
  const rows = details.map((job) => el("tr", { "data-job": job.id },
    el("td", { "data-label": "Job", class: "job-name" },
      el("a", { href: `#/job/${job.id}`, title: job.id }, jobName(job)),
      el("span", { class: "job-id" }, job.id.slice(0, 8))),
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
  $("#jobs-empty").hidden = Boolean(rows.length);
  $("#jobs-count").textContent = page.total ? `${page.total} job${page.total === 1 ? "" : "s"}` +
    (state.me.admin ? " (everyone's)" : "") : "";
  $("#jobs-more").hidden = !page.next;
  if (!$("#view-jobs").hidden) poll(refreshJobs);
}

// --- one job ---------------------------------------------------------------------------------

function rangeText(range) {
  if (!range) return "—";
  const how = { given: "given", auto: "estimated from the views", "auto-fallback": "fallback" }[range.source] ?? range.source;
  return `0–${range.max_disparity} px (${how})${range.note ? `: ${range.note}` : ""}`;
}

function keyValues(entries) {
  return el("dl", { class: "kv" }, entries.flatMap(([name, value]) => [el("dt", {}, name), el("dd", {}, value)]));
}

function colourBar(bar, label) {
  const top = bar.scale;
  const ticks = [0, top / 2, top].map((value) => el("span", {}, `${fmt(value, 3)} px`));
  bar.img.className = "colourbar-img";
  return el("figure", { class: "colourbar" }, bar.img, el("div", { class: "ticks" }, ticks),
    el("figcaption", {}, label));
}

async function resultImages(job, { withLeft = true } = {}) {
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

function metricsBlock(job) {
  if (!job.metrics) return null;
  // fixed decimals: an RMSE of 1.002 px must not read "1 px"
  const metric = (value, name) => el("div", { class: "metric" },
    el("span", { class: "metric-value" }, value), el("span", { class: "metric-name" }, name));
  return el("div", { class: "metrics", "aria-label": "metrics" },
    metric(`${job.metrics.rmse.toFixed(3)} px`, "RMSE"),
    metric(`${job.metrics.bpp.toFixed(2)} %`, "bad pixels (> 1 px)"),
    metric(String(job.metrics.pixels), "pixels evaluated"));
}

/** What "repaired" counts (the API's LevelTiming.repaired says the same). */
const REPAIRED_NOTE = "Repaired: pixels whose QUBO sample was not a valid label encoding " +
  "(one-hot: no bit or several bits set; domain-wall: a broken wall) and that were given their " +
  "cheapest label next to their valid neighbours, with their share of the level's pixels. A " +
  "high share means the solver's samples are far from valid: its chain strength or read count " +
  "is too low for these bundles. The exact row solver never needs a repair.";

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
  const page = await json("/v1/jobs?limit=100");
  const others = page.items.filter((other) => other.id !== job.id && other.state === "succeeded" &&
    other.width === job.width && other.height === job.height);
  if (!others.length) return el("p", { class: "muted" }, "Compare: no other finished job of this size yet.");
  const select = el("select", { id: "compare-with" }, others.map((other) =>
    el("option", { value: other.id }, `${jobName(other)} · ${other.solver} · ${age(other.created_at)}`)));
  return el("div", { class: "compare-pick" }, el("label", { for: "compare-with" }, "Compare with"), select,
    el("button", { type: "button", class: "small", onclick: () => { location.hash = `#/compare/${job.id}/${select.value}`; } }, "Compare"));
}

function warningsBlock(job) {
  if (!job.warnings?.length) return null;
  return el("div", { class: "card notice warnings", role: "status", "aria-label": "warnings" },
    job.warnings.map((text) => el("p", {}, text)));
}

function groundTruthText(job) {
  const truth = job.ground_truth;
  if (!truth) return "none (no metrics)";
  return `scale ${fmt(truth.scale)}${truth.inferred ? " (inferred from the views)" : ""}, ` +
    `border ${truth.border} px`;
}

async function showJob(id) {
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
  const parts = [
    el("div", { class: "title-row" },
      el("h1", {}, job.label || `Job ${job.id.slice(0, 8)}`), stateBadge(job.state),
      active ? el("button", { type: "button", class: "small danger", onclick: () => cancelJob(job.id) }, "Cancel") : null),
    warningsBlock(job),
    keyValues(facts),
  ];
  if (active || job.state === "succeeded") parts.push(progressBar(job));
  if (job.error) parts.push(el("p", { class: "field-error", role: "alert" }, job.error));
  if (job.state === "succeeded") {
    parts.push(metricsBlock(job));
    parts.push(await resultImages(job));
    parts.push(el("div", { class: "downloads" }, el("span", {}, "Download:"),
      [["pfm", "PFM"], ["png", "16-bit PNG"], ["npy", "NPY"]].map(([format, label]) =>
        el("button", { type: "button", class: "small", onclick: () => download(`/v1/jobs/${job.id}/disparity?format=${format}`, `${job.id}.${format}`) }, label))));
    parts.push(await compareChooser(job));
  }
  parts.push(el("h2", {}, "Levels"), levelsTable(job) ?? el("p", { class: "muted" }, "No level finished yet."));
  parts.push(el("h2", {}, "Solver usage"), usageList(job.usage));
  parts.push(el("details", { class: "params-box" }, el("summary", {}, "Parameters (JSON)"),
    el("pre", { class: "params" }, JSON.stringify(job.config, null, 2))));
  view.replaceChildren(...parts.filter(Boolean));
  if (active) poll(() => showJob(id));
}

async function differenceImage(a, b) {
  const response = await api(`/v1/jobs/${a.id}/difference.png?with=${b.id}`);
  const url = URL.createObjectURL(await response.blob());
  state.urls.push(url);
  const bar = await authImage(`/v1/jobs/${a.id}/colorbar.png?map=error`, "Difference colour scale");
  const differing = Number(response.headers.get("X-Differing-Percent"));
  return el("figure", { class: "shot difference" },
    el("img", { src: url, alt: "Difference" }),
    colourBar(bar, `|${a.solver} − ${b.solver}| in px: ${fmt(differing, 3)} % of the pixels differ by more than 1 px`));
}

async function showCompare(a, b) {
  showView("compare");
  const view = $("#view-compare");
  const jobs = await Promise.all([a, b].map((id) => json(`/v1/jobs/${id}`)));
  const columns = await Promise.all(jobs.map(async (job) => {
    return el("div", { class: "column" },
      el("h2", {}, el("a", { href: `#/job/${job.id}` }, `${job.solver} · ${jobName(job)}`)),
      metricsBlock(job),
      job.state === "succeeded" ? await resultImages(job, { withLeft: false }) : el("p", {}, `state: ${job.state}`),
      keyValues([["duration", duration(jobDuration(job))], ["solver time", seconds(job.usage.solver_seconds)],
        ["final energy", fmt(job.levels.at(-1)?.energy, 5)]]));
  }));
  const both = jobs.every((job) => job.state === "succeeded");
  const difference = both ? await differenceImage(jobs[0], jobs[1]).catch((error) =>
    el("p", { class: "field-error", role: "alert" }, error.message)) : null;
  const parts = [el("h1", {}, "Compare"), el("div", { class: "compare" }, columns)];
  if (difference) parts.push(el("div", { class: "difference-row" }, el("h2", {}, "Difference"), difference));
  view.replaceChildren(...parts);
}

// --- usage and users -------------------------------------------------------------------------

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

async function showUsage() {
  showView("usage");
  const usage = await json("/v1/usage");
  const cards = usage.users.map((entry) => el("div", { class: "card usage-card", "data-user": entry.user },
    el("h2", {}, entry.user),
    budgetBar(entry),
    keyValues([["used", seconds(entry.used_seconds)], ["reserved", seconds(entry.reserved_seconds)],
      ["left", entry.remaining_seconds === null ? "unlimited" : seconds(entry.remaining_seconds)],
      ["budget", entry.limit_seconds === null ? "unlimited" : seconds(entry.limit_seconds)]]),
    entry.jobs.length
      ? el("table", { class: "small-table" }, el("thead", {}, el("tr", {}, el("th", {}, "Job"), el("th", {}, "QPU time"), el("th", {}, "Problems"))),
        el("tbody", {}, entry.jobs.map((job) => el("tr", {},
          el("td", {}, el("a", { href: `#/job/${job.id}` }, job.id.slice(0, 8))),
          el("td", {}, seconds(job.qpu_seconds)), el("td", {}, job.problems)))))
      : el("p", { class: "muted" }, "No QPU time charged yet.")));
  $("#view-usage").replaceChildren(
    el("h1", {}, "QPU usage"),
    el("p", { class: "muted" }, `QPU access time (hybrid: charge time) charged to ${state.me.admin ? "every user" : "you"}; ` +
      `total ${seconds(usage.total_used_seconds)}` + (usage.qpu_in_flight === null || usage.qpu_in_flight === undefined ? "" : `, ${usage.qpu_in_flight} problem(s) in flight lab-wide`)),
    el("div", { class: "cards" }, cards));
}

function issuedKey(name, key) {
  const box = $("#issued-key");
  box.replaceChildren(el("p", {}, `API key of ${name} — shown once, copy it now:`),
    el("code", { class: "key", id: "issued-key-value" }, key));
  box.hidden = false;
}

async function userAction(action) {
  $("#users-error").textContent = "";
  try { await action(); } catch (error) {
    if (error.status !== 401) $("#users-error").textContent = error.message;
  }
  await refreshUsers();
}

async function refreshUsers() {
  const users = await json("/v1/users");
  $("#users-table tbody").replaceChildren(...users.map((user) => {
    const quota = el("input", { type: "number", min: "0", step: "any", class: "quota",
      "aria-label": `QPU budget of ${user.name}`, placeholder: "unlimited",
      value: user.limit_seconds === null ? "" : String(user.limit_seconds) });
    return el("tr", { "data-user": user.name },
      el("td", { "data-label": "User" }, user.name),
      el("td", { "data-label": "Role" }, user.admin ? "admin" : "member"),
      el("td", { "data-label": "Key" }, user.revoked ? stateBadge("revoked") : el("code", {}, user.key_id ?? "—")),
      el("td", { "data-label": "Used s" }, fmt(user.used_seconds)),
      el("td", { "data-label": "Budget s" }, user.limit_seconds === null ? "unlimited" : fmt(user.limit_seconds)),
      el("td", { "data-label": "Set budget" }, el("div", { class: "inline" }, quota,
        el("button", { type: "button", class: "small", onclick: () => userAction(() =>
          send(`/v1/users/${encodeURIComponent(user.name)}/quota`, "PUT",
            { qpu_seconds: quota.value.trim() === "" ? null : Number(quota.value) })) }, "Set"))),
      el("td", { class: "actions" },
        el("button", { type: "button", class: "small", onclick: () => userAction(async () => {
          const issued = await send(`/v1/users/${encodeURIComponent(user.name)}/key`, "POST");
          issuedKey(user.name, issued.key);
        }) }, "Rotate key"),
        user.revoked || user.name === state.me.name ? null
          : el("button", { type: "button", class: "small danger", onclick: () => userAction(() =>
            send(`/v1/users/${encodeURIComponent(user.name)}/key`, "DELETE")) }, "Revoke")));
  }));
}

async function showUsers() {
  showView("users");
  await refreshUsers();
}

async function createUser(event) {
  event.preventDefault();
  const form = event.currentTarget;
  clearErrors(form);
  $("#issued-key").hidden = true;
  const payload = { name: $("#new-user-name").value.trim(), admin: $("#new-user-admin").checked };
  const budget = $("#new-user-budget").value.trim();
  if (budget) payload.qpu_seconds = Number(budget);
  try {
    const issued = await send("/v1/users", "POST", payload);
    issuedKey(issued.user.name, issued.key);
    form.reset();
    await refreshUsers();
  } catch (error) {
    if (error.status === 401) return;
    if (Array.isArray(error.detail)) {
      for (const item of error.detail) showFieldError(form, String(item.loc?.at(-1) ?? "form"), item.msg);
    } else {
      showFieldError(form, /user name|exists/.test(error.message) ? "name" : "form", error.message);
    }
  }
}

// --- start -----------------------------------------------------------------------------------

async function start() {
  setUpDropZones();
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
  $("#submit-form").addEventListener("submit", submitJob);
  $("#estimate-button").addEventListener("click", estimateJob);
  $("#solver").addEventListener("change", describeSolver);
  $("#create-user-form").addEventListener("submit", createUser);
  $("#jobs-more").addEventListener("click", () => { state.jobsLimit = Math.min(100, state.jobsLimit + 20); refreshJobs(); });
  window.addEventListener("hashchange", () => (fragmentKey() ? signInFromFragment() : render()));
  await signInFromFragment();
}

/** The key of a `#key=...` address (what `qhsm serve` prints), if this is one. */
function fragmentKey() {
  const fragment = location.hash.match(/^#key=(.+)$/);
  return fragment ? decodeURIComponent(fragment[1]) : null;
}

/** Who a key belongs to (GET /v1/me with it), without signing in with it. */
async function whoIs(candidate) {
  const response = await fetch("/v1/me", { headers: { Authorization: `Bearer ${candidate}` } });
  if (!response.ok) {
    const data = await body(response);
    throw new ApiError(response.status, data.detail ?? `HTTP ${response.status}`);
  }
  return response.json();
}

function describe(user) { return `${user.name}${user.admin ? " (admin)" : ""}`; }

/** Ask before a link's key signs this tab in: a link to `#key=<someone else's key>` must never
 * switch accounts silently (the uploads would go to that account). Resolves to the choice. */
function confirmSwitch(next) {
  return new Promise((resolve) => {
    stopPolling();
    $("#nav").hidden = true;
    $("#switch-to").textContent = describe(next);
    $("#switch-from").hidden = !state.me;
    if (state.me) $("#switch-current").textContent = describe(state.me);
    $("#switch-accept").textContent = `Sign in as ${next.name}`;
    $("#switch-decline").textContent = state.me ? `Stay ${state.me.name}` : "Cancel";
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
async function signInFromFragment() {
  const fromFragment = fragmentKey();
  if (fromFragment) history.replaceState(null, "", `${location.pathname}#/jobs`);
  if (key() && !state.me) {
    try {
      await signIn(key());
    } catch (error) {
      sessionStorage.removeItem(KEY_STORAGE);
      state.me = null;
    }
  }
  if (fromFragment && fromFragment !== key()) {
    try {
      const next = await whoIs(fromFragment);
      const same = state.me && state.me.name === next.name;
      if (same || (await confirmSwitch(next))) await signIn(fromFragment);
    } catch (error) {
      $("#signin-error").textContent = error.message;
    }
  }
  render();
}

start();
