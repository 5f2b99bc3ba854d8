// Two finished jobs of one size side by side, and the map of where their disparities differ.

import { api, authImage, imageUrl, json } from "./api.js";
import { $, el, keyValues } from "./dom.js";
import { duration, fmt, jobDuration, jobName, seconds } from "./format.js";
import { colourBar, metricsBlock, resultImages } from "./job.js";
import { showView } from "./views.js";

async function differenceImage(a, b) {
  const response = await api(`/v1/jobs/${a.id}/difference.png?with=${b.id}`);
  const src = await imageUrl(response);
  const bar = await authImage(`/v1/jobs/${a.id}/colorbar.png?map=error`, "Difference colour scale");
  const differing = Number(response.headers.get("X-Differing-Percent"));
  return el("figure", { class: "shot difference" },
    el("img", { src, alt: "Difference" }),
    colourBar(bar, `|${a.solver} − ${b.solver}| in px: ${fmt(differing)} % of the pixels differ by more than 1 px`));
}

export async function showCompare(a, b) {
  showView("compare");
  const view = $("#view-compare");
  const jobs = await Promise.all([a, b].map((id) => json(`/v1/jobs/${id}`)));
  const columns = await Promise.all(jobs.map(async (job) => el("div", { class: "column" },
    el("h2", {}, el("a", { href: `#/job/${job.id}` }, `${job.solver} · ${jobName(job)}`)),
    metricsBlock(job),
    job.state === "succeeded" ? await resultImages(job, { withLeft: false }) : el("p", {}, `state: ${job.state}`),
    keyValues([["duration", duration(jobDuration(job))], ["solver time", seconds(job.usage.solver_seconds)],
      ["final energy", fmt(job.levels.at(-1)?.energy, 5)]]))));
  const both = jobs.every((job) => job.state === "succeeded");
  const difference = both ? await differenceImage(jobs[0], jobs[1]).catch((error) =>
    el("p", { class: "field-error", role: "alert" }, error.message)) : null;
  const parts = [el("h1", {}, "Compare"), el("div", { class: "compare" }, columns)];
  if (difference) parts.push(el("div", { class: "difference-row" }, el("h2", {}, "Difference"), difference));
  view.replaceChildren(...parts);
}
