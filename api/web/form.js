// The submit view: the upload form, its choices from the server, file previews, the estimate
// before submitting, and the API's errors shown at the fields they are about.

import { api, json } from "./api.js";
import { $, clearErrors, el, showFieldError } from "./dom.js";
import { fmt, seconds } from "./format.js";
import { showView } from "./views.js";

/** The schemas of /openapi.json, fetched once. */
let apiSchemas = null;
/** The server's solvers by name (GET /v1/solvers), for the note under the choice. */
let solvers = null;
/** Settles when the form's choices are loaded: a request built before would miss the defaults. */
let choicesLoaded = null;

/** MatchConfig's JSON schema from /openapi.json: which presets and encodings this server has. */
async function matchSchema() {
  if (!apiSchemas) {
    const openapi = await (await fetch("/openapi.json")).json();
    apiSchemas = openapi.components.schemas;
  }
  return apiSchemas;
}

function enumOf(schemas, name) {
  return schemas[name]?.enum ?? [];
}

export function showSubmit() {
  showView("submit");
  choicesLoaded = loadSubmitChoices();
  return choicesLoaded;
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
  const available = await json("/v1/solvers");
  const select = $("#solver");
  const previous = select.value || "exact";
  select.replaceChildren(...available.map((s) => el("option", {
    value: s.name, disabled: !s.available, selected: s.name === previous,
    title: s.available ? s.description : s.reason,
  }, s.available ? `${s.name}${s.offline ? " (offline)" : ""}` : `${s.name} — unavailable: ${s.reason}`)));
  solvers = Object.fromEntries(available.map((s) => [s.name, s]));
  describeSolver();
}

function describeSolver() {
  const info = solvers?.[$("#solver").value];
  $("#solver-note").textContent = info
    ? `${info.description}${info.uses_qpu_time ? " · uses QPU time from your budget" : ""}`
    : "";
}

/** Which form field an API error is about: FastAPI's loc, or the field the message starts with. */
function fieldOfError(detail) {
  const isField = (name) => [...$("#submit-form").elements].some((control) => control.name === name);
  if (Array.isArray(detail)) {
    return detail.map((item) => [String(item.loc?.at(-1) ?? "form"), item.msg]);
  }
  const text = String(detail);
  const param = text.match(/^params: ([a-z_]+)/);
  if (param && isField(param[1])) return [[param[1], text]];
  if (/^params: unknown solver/.test(text)) return [["solver", text]];
  if (param) return [["solver_params", text]];
  if (/^solver /.test(text)) return [["solver", text]];
  if (/ but right is /.test(text)) return [["right", text]];
  const form = text.match(/^(gt_scale|gt_border|label|tags)\b/);
  if (form) return [[form[1], text]];
  const file = text.match(/^(left|right|ground_truth)\b/);
  if (file) return [[file[1], text]];
  if (/QPU|budget/i.test(text)) return [["solver", text]];
  return [["form", text]];
}

function showApiError(form, error) {
  if (error.status === 401) return; // signed out: the sign-in view says so
  for (const [field, message] of fieldOfError(error.detail)) showFieldError(form, field, message);
}

/** The form as the API's multipart body (null, with the fields' errors shown, when invalid). */
async function jobRequest(form) {
  clearErrors(form);
  await choicesLoaded;
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
  const tags = $("#tags").value.trim();
  if (tags) data.append("tags", tags);
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
  for (const name of ["ground_truth", "gt_scale", "gt_border", "label", "tags"]) data.delete(name);
  out.textContent = "Estimating…";
  try {
    // computed on a worker: poll the estimate until it ends (GET /v1/estimates/{id})
    let status = await json("/v1/estimate", { method: "POST", body: data });
    for (let wait = 100; status.state === "pending" || status.state === "running"; wait = Math.min(1000, wait * 1.5)) {
      await new Promise((resolve) => setTimeout(resolve, wait));
      status = await json(status.links.self);
    }
    if (status.state !== "done") {
      out.textContent = `Estimate ${status.state}: ${status.error}`;
      return;
    }
    const e = status.result;
    out.textContent = !e.metered ? `${e.solver} is not metered: no QPU time is charged.`
      : `${seconds(e.seconds)} of ${e.levels[0]?.qubits_per_bundle === null ? "hybrid" : "QPU"} time; ` +
        `${fmt(100 * e.classical_share, 2)} % of ${e.bundles} bundles solved classically (tile certificates, roof duality); ` +
        (e.fits ? "fits your budget." : "does NOT fit your budget.");
  } catch (error) {
    out.textContent = "";
    showApiError(form, error);
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
    showApiError(form, error);
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

/** Each `.drop` of the page takes its file by a drop too, and shows the file's thumbnail: the
 * hint and the thumbnail are made here, with the behaviour they belong to. */
function setUpDropZones() {
  for (const zone of document.querySelectorAll(".drop")) {
    const input = $(`#${zone.dataset.input}`);
    input.after(el("p", { class: "hint" }, "or drop a file here"), el("img", { class: "thumb", alt: "", hidden: true }));
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

export function setUpSubmitForm() {
  setUpDropZones();
  $("#submit-form").addEventListener("submit", submitJob);
  $("#estimate-button").addEventListener("click", estimateJob);
  $("#solver").addEventListener("change", describeSolver);
}
