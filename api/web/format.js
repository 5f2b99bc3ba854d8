// Numbers, durations and job facts as the page writes them (no DOM here).

export function fmt(value, digits = 3) {
  if (value === null || value === undefined) return "—";
  if (typeof value !== "number") return String(value);
  if (Number.isInteger(value)) return String(value);
  return value.toPrecision(digits).replace(/\.?0+(e|$)/, "$1");
}

export function seconds(value) {
  if (value === null || value === undefined) return "—";
  if (value < 1e-3 && value > 0) return `${fmt(value * 1e6)} µs`;
  if (value < 1) return `${fmt(value * 1e3)} ms`;
  return `${fmt(value)} s`;
}

/** A duration in seconds as people read it: 0.8 s, 12.3 s, 3 min 08 s, 1 h 02 min. */
export function duration(value) {
  if (value === null || value === undefined || !Number.isFinite(value)) return "—";
  if (value < 60) return `${value < 10 ? value.toFixed(1) : Math.round(value)} s`;
  const minutes = Math.floor(value / 60);
  if (minutes < 60) return `${minutes} min ${String(Math.round(value % 60)).padStart(2, "0")} s`;
  return `${Math.floor(minutes / 60)} h ${String(minutes % 60).padStart(2, "0")} min`;
}

export function age(iso) {
  const delta = Math.max(0, (Date.now() - Date.parse(iso)) / 1000);
  if (delta < 60) return `${Math.round(delta)} s ago`;
  if (delta < 3600) return `${Math.round(delta / 60)} min ago`;
  if (delta < 86400) return `${Math.round(delta / 3600)} h ago`;
  return `${Math.round(delta / 86400)} d ago`;
}

/** How long a job ran: started to finished, or to now while it runs. */
export function jobDuration(job) {
  if (!job.started_at) return null;
  const end = job.finished_at ? Date.parse(job.finished_at) : Date.now();
  return Math.max(0, (end - Date.parse(job.started_at)) / 1000);
}

/** What a job is called: its label, else its files' names, else its short id. */
export function jobName(job) {
  if (job.label) return job.label;
  if (job.files?.length) return job.files.join(" · ");
  return job.id.slice(0, 8);
}

export function scoresText(job) {
  if (!job.metrics) return "—";
  const { rmse, bpp } = job.metrics;
  return `${rmse === null ? "n/a" : rmse.toFixed(3)} px · ${bpp === null ? "n/a" : bpp.toFixed(2)} %`;
}

export function rangeText(range) {
  if (!range) return "—";
  const how = { given: "given", auto: "estimated from the views", "auto-fallback": "fallback" }[range.source] ?? range.source;
  return `0–${range.max_disparity} px (${how})${range.note ? `: ${range.note}` : ""}`;
}

export function groundTruthText(job) {
  const truth = job.ground_truth;
  if (!truth) return "none (no metrics)";
  return `scale ${fmt(truth.scale)}${truth.inferred ? " (inferred from the views)" : ""}, ` +
    `border ${truth.border} px`;
}

export function userText(user) { return `${user.name}${user.admin ? " (admin)" : ""}`; }
