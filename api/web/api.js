// Calls to the /v1 API with the tab's key. The key lives in this tab's sessionStorage and goes
// out as a Bearer header; `session.me` is who it belongs to (null: signed out).

import { el } from "./dom.js";

const KEY_STORAGE = "qhsm.key";

export const session = { me: null };

/** Object URLs of the images shown, freed when the page shows another job. */
let imageUrls = [];
let unauthorized = () => {};

class ApiError extends Error {
  constructor(status, detail) {
    super(typeof detail === "string" ? detail : JSON.stringify(detail));
    this.status = status;
    this.detail = detail;
  }
}

export function storedKey() { return sessionStorage.getItem(KEY_STORAGE); }

export function forgetKey() {
  sessionStorage.removeItem(KEY_STORAGE);
  session.me = null;
}

/** What to do when the API refuses the key (401): set by the entry, which owns sign-out. */
export function onUnauthorized(handler) { unauthorized = handler; }

export async function api(path, options = {}) {
  const headers = new Headers(options.headers || {});
  if (storedKey()) headers.set("Authorization", `Bearer ${storedKey()}`);
  const response = await fetch(path, { ...options, headers });
  if (response.status === 401) {
    unauthorized((await body(response)).detail);
    throw new ApiError(401, "signed out");
  }
  if (!response.ok) throw await errorOf(response);
  return response;
}

async function body(response) {
  try { return await response.json(); } catch { return {}; }
}

async function errorOf(response) {
  const data = await body(response);
  return new ApiError(response.status, data.detail ?? `HTTP ${response.status}`);
}

export async function json(path, options) { return (await api(path, options)).json(); }

export async function send(path, method, payload) {
  return json(path, {
    method, headers: { "Content-Type": "application/json" },
    body: payload === undefined ? undefined : JSON.stringify(payload),
  });
}

/** Who a key belongs to (GET /v1/me with it), without signing in with it. */
export async function whoIs(candidate) {
  const response = await fetch("/v1/me", { headers: { Authorization: `Bearer ${candidate}` } });
  if (!response.ok) throw await errorOf(response);
  return response.json();
}

export async function signIn(candidate) {
  const me = await whoIs(candidate);
  sessionStorage.setItem(KEY_STORAGE, candidate);
  session.me = me;
}

/** An object URL of a response's bytes, kept until `releaseImages`. */
export async function imageUrl(response) {
  const url = URL.createObjectURL(await response.blob());
  imageUrls.push(url);
  return url;
}

export function releaseImages() {
  for (const url of imageUrls) URL.revokeObjectURL(url);
  imageUrls = [];
}

/** An <img> whose bytes are fetched with the key (an <img src> cannot send headers). */
export async function authImage(path, alt) {
  const response = await api(path);
  const src = await imageUrl(response);
  return { img: el("img", { src, alt }), scale: Number(response.headers.get("X-Scale-Max")) };
}

export async function download(path, filename) {
  const response = await api(path);
  const url = URL.createObjectURL(await response.blob());
  const link = el("a", { href: url, download: filename });
  document.body.append(link);
  link.click();
  link.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
}
