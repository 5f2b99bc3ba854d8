// The admins' view of users: create one (its key shown once), set budgets and their periods,
// rotate and revoke keys.

import { json, send, session } from "./api.js";
import { $, clearErrors, el, showFieldError, stateBadge } from "./dom.js";
import { fmt } from "./format.js";
import { showView } from "./views.js";

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
    const path = `/v1/users/${encodeURIComponent(user.name)}`;
    const quota = el("input", { type: "number", min: "0", step: "any", class: "quota",
      "aria-label": `QPU budget of ${user.name}`, placeholder: "unlimited",
      value: user.limit_seconds === null ? "" : String(user.limit_seconds) });
    const period = el("select", { class: "period", "aria-label": `Budget period of ${user.name}` },
      ["", "lifetime", "monthly", "weekly"].map((value) => el("option", { value,
        selected: (user.own_period ?? "") === value },
      value || `default (${user.own_period ? "QHSM_BUDGET_PERIOD" : user.period})`)));
    return el("tr", { "data-user": user.name },
      el("td", { "data-label": "User" }, user.name),
      el("td", { "data-label": "Role" }, user.admin ? "admin" : "member"),
      el("td", { "data-label": "Key" }, user.revoked ? stateBadge("revoked") : el("code", {}, user.key_id ?? "—")),
      el("td", { "data-label": "Used s" }, fmt(user.used_seconds)),
      el("td", { "data-label": "Budget s" }, user.limit_seconds === null ? "unlimited" : fmt(user.limit_seconds)),
      el("td", { "data-label": "Set budget" }, el("div", { class: "inline" }, quota, period,
        el("button", { type: "button", class: "small", onclick: () => userAction(() =>
          send(`${path}/quota`, "PUT",
            { qpu_seconds: quota.value.trim() === "" ? null : Number(quota.value),
              period: period.value || null })) }, "Set"))),
      el("td", { class: "actions" },
        el("button", { type: "button", class: "small", onclick: () => userAction(async () => {
          const issued = await send(`${path}/key`, "POST");
          issuedKey(user.name, issued.key);
        }) }, "Rotate key"),
        user.revoked || user.name === session.me.name ? null
          : el("button", { type: "button", class: "small danger", onclick: () => userAction(() =>
            send(`${path}/key`, "DELETE")) }, "Revoke")));
  }));
}

export async function showUsers() {
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

export function setUpUserForm() {
  $("#create-user-form").addEventListener("submit", createUser);
}
