// The API client: the session's token, JSON requests that stop when their view is left (an
// AbortSignal), and CSV downloads.

export const API = "/api/v1";

/** The signed-in session: the token (kept for the browser session) and who it is. */
export const session = { token: sessionStorage.getItem("tc_token"), me: null, onUnauthorized: () => {} };

/** A refused request: its HTTP status and the API's detail, in words. */
export class ApiError extends Error {
  constructor(status, detail) {
    super(typeof detail === "string" ? detail : formatDetail(detail));
    this.status = status;
    this.detail = detail;
  }
}

function formatDetail(detail) {
  if (Array.isArray(detail)) {
    return detail.map((d) => `${(d.loc || []).filter((x) => x !== "body").join(".")}: ${d.msg}`).join("; ");
  }
  return JSON.stringify(detail);
}

/** Whether `err` is a request stopped because its view was left (not a failure). */
export const aborted = (err) => err?.name === "AbortError";

/** The API's JSON answer to `path` (under /api/v1); `options.signal` stops it. */
export async function api(path, options = {}) {
  const headers = { Authorization: `Bearer ${session.token}` };
  if (options.body) headers["Content-Type"] = "application/json";
  const reply = await fetch(API + path, { ...options, headers });
  const body = reply.headers.get("content-type")?.includes("json") ? await reply.json() : null;
  if (reply.status === 401) { session.onUnauthorized(); throw new ApiError(401, body?.detail || "not signed in"); }
  if (!reply.ok) throw new ApiError(reply.status, body?.detail ?? reply.statusText);
  return body;
}

/** Downloads the CSV at `path` (under /api/v1) as a file: fetched with the token, saved under the
 *  name the API gives it (Content-Disposition). Returns the file name. */
export async function download(path, options = {}) {
  const reply = await fetch(API + path, { ...options, headers: { Authorization: `Bearer ${session.token}` } });
  if (reply.status === 401) { session.onUnauthorized(); throw new ApiError(401, "not signed in"); }
  if (!reply.ok) {
    const body = reply.headers.get("content-type")?.includes("json") ? await reply.json() : null;
    throw new ApiError(reply.status, body?.detail ?? reply.statusText);
  }
  const name = (reply.headers.get("content-disposition") || "").match(/filename="([^"]+)"/)?.[1] || "export.csv";
  const url = URL.createObjectURL(await reply.blob());
  const link = document.createElement("a");
  link.href = url;
  link.download = name;
  link.hidden = true;
  document.body.append(link);
  link.click();
  link.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10_000);
  return name;
}
