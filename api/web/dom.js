// Building and finding elements, the toast, and the field errors of the page's forms.

export const $ = (selector, root = document) => root.querySelector(selector);

export function el(tag, attrs = {}, ...children) {
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

export function keyValues(entries) {
  return el("dl", { class: "kv" }, entries.flatMap(([name, value]) => [el("dt", {}, name), el("dd", {}, value)]));
}

export function stateBadge(value) { return el("span", { class: `badge ${value}` }, value); }

let toastTimer = null;

export function toast(message) {
  const box = $("#toast");
  box.textContent = message;
  box.hidden = false;
  clearTimeout(toastTimer);
  toastTimer = setTimeout(() => { box.hidden = true; }, 4000);
}

/** The slot each field of the page's forms shows its errors in (``data-field``: the name of the
 * field's control, as the API's errors name it), made here once for every field rather than
 * written beside each control of index.html. */
export function addErrorSlots(root = document) {
  for (const field of root.querySelectorAll(".field, .drop")) {
    const control = field.querySelector("[name]");
    if (control) field.append(el("p", { class: "field-error", "data-field": control.name, role: "alert" }));
  }
}

export function clearErrors(form) {
  for (const node of form.querySelectorAll(".field-error")) node.textContent = "";
  for (const node of form.querySelectorAll("[aria-invalid]")) node.removeAttribute("aria-invalid");
}

export function showFieldError(form, field, message) {
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
