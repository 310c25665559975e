// The REST and WebSocket API as the studio calls it: the token (kept in
// this browser's localStorage) goes in `Authorization`, or `access_token`
// for a WebSocket; an error answer becomes an ApiError carrying the
// server's `{error: {code, field, reason}}`.

export class ApiError extends Error {
  constructor(status, body) {
    const e = (body && body.error) || {};
    const where = e.field ? `${e.field}: ` : "";
    super(`${status} ${e.code || "error"} — ${where}${e.reason || "no reason given"}`);
    this.status = status;
    this.code = e.code;
    this.field = e.field;
    this.reason = e.reason;
  }
}

export function token() {
  return localStorage.getItem("choreo.token") || "";
}

export function setToken(t) {
  if (t) localStorage.setItem("choreo.token", t);
  else localStorage.removeItem("choreo.token");
}

function headers(extra = {}) {
  const h = { ...extra };
  const t = token();
  if (t) h.Authorization = `Bearer ${t}`;
  return h;
}

async function answer(r) {
  if (r.ok) return r;
  let body = null;
  try {
    body = await r.json();
  } catch (_) {
    body = { error: { code: "error", reason: r.statusText || "no body" } };
  }
  throw new ApiError(r.status, body);
}

export async function get(path) {
  return (await answer(await fetch(path, { headers: headers() }))).json();
}

export async function post(path, body) {
  const r = await fetch(path, {
    method: "POST",
    headers: headers({ "Content-Type": "application/json" }),
    body: JSON.stringify(body),
  });
  return (await answer(r)).json();
}

/** A download (BVH, glb, JSON) fetched with the token, saved by the browser. */
export async function download(path, filename) {
  const r = await answer(await fetch(path, { headers: headers() }));
  saveBlob(await r.blob(), filename);
}

export function saveBlob(blob, filename) {
  const url = URL.createObjectURL(blob);
  const a = document.createElement("a");
  a.href = url;
  a.download = filename;
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
}

export function socket(path) {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  const t = token();
  const q = t ? `?access_token=${encodeURIComponent(t)}` : "";
  return new WebSocket(`${proto}//${location.host}${path}${q}`);
}

/** A file as base64, for `{"file": {"name", "content_base64"}}`. */
export function fileBase64(file) {
  return new Promise((resolve, reject) => {
    const r = new FileReader();
    r.onload = () => resolve(String(r.result).split(",", 2)[1] || "");
    r.onerror = () => reject(r.error);
    r.readAsDataURL(file);
  });
}
