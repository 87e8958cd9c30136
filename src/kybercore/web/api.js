// The REST API of the KyberCore backend. Every failure becomes an ApiError carrying the
// backend's {code, message, reasons, fields}; nothing here invents a success.
import { t } from "./i18n.js";

/**
 * One finding of a check (ReasonOut), in both languages.
 * @typedef {{code: string, level: "ok" | "warn" | "block", category?: string, en: string, es: string}} Reason
 * @typedef {{field: string, en: string, es: string}} FieldProblem one field of a 422 (FieldError)
 * @typedef {{code?: string, message?: string, reasons?: Reason[], fields?: FieldProblem[]}} ErrorBody
 */

export class ApiError extends Error {
  /**
   * @param {number} status the HTTP status (0: no answer)
   * @param {ErrorBody | null | undefined} error the answer's {"error": {...}}
   */
  constructor(status, error) {
    super((error && error.message) || `HTTP ${status}`);
    this.status = status;
    this.code = (error && error.code) || `http_${status}`;
    /** @type {Reason[]} */
    this.reasons = (error && error.reasons) || [];
    // 422 invalid_input: [{field: "capabilities.material", en, es}] (dotted paths).
    /** @type {FieldProblem[]} */
    this.fields = (error && error.fields) || [];
  }
}

const enc = encodeURIComponent;

async function request(method, path, body) {
  let response;
  try {
    response = await fetch(path, {
      method,
      headers: body === undefined ? {} : { "Content-Type": "application/json" },
      body: body === undefined ? undefined : JSON.stringify(body),
    });
  } catch {
    throw new ApiError(0, { code: "network", message: t("error.network") });
  }
  if (response.status === 401) window.dispatchEvent(new CustomEvent("kybercore:unauthorized"));
  if (response.status === 204) return null;
  let data = null;
  try {
    data = await response.json();
  } catch {
    data = null;
  }
  if (!response.ok) {
    throw new ApiError(response.status, (data && data.error) || { message: `HTTP ${response.status} ${response.statusText}` });
  }
  return data;
}

const printer = (id) => `/api/printers/${enc(id)}`;

export const api = {
  session: () => request("GET", "/api/session"),
  login: (token) => request("POST", "/api/session", { token }),
  logout: () => request("DELETE", "/api/session"),
  // check: save only if Moonraker answers (the form's connection test).
  addPrinter: (body, { check = false } = {}) => request("POST", check ? "/api/printers?check=true" : "/api/printers", body),
  updatePrinter: (id, body) => request("PATCH", printer(id), body),
  removePrinter: (id) => request("DELETE", printer(id)),
  act: (id, action, params = {}) => request("POST", `${printer(id)}/actions/${enc(action)}`, params),
  check: (id, action, params = {}) => request("POST", `${printer(id)}/actions/${enc(action)}/check`, params),
  gcode: (id, script, options = {}) => request("POST", `${printer(id)}/gcode`, { script, ...options }),
  console: (id, count = 100) => request("GET", `${printer(id)}/console?count=${count}`),
  files: (id) => request("GET", `${printer(id)}/files`),
  deleteFile: (id, path) => request("DELETE", `${printer(id)}/files?path=${enc(path)}`),
  metadata: (id, filename) => request("GET", `${printer(id)}/files/metadata?filename=${enc(filename)}`),
  thumbnailUrl: (id, path) => `${printer(id)}/files/thumbnail?path=${enc(path)}`,
  actMany: (action, ids, params = {}) =>
    request("POST", `/api/fleet/actions/${enc(action)}`, { ...params, printer_ids: ids }),
  checkMany: (action, ids, params = {}) =>
    request("POST", `/api/fleet/actions/${enc(action)}/check`, { ...params, printer_ids: ids }),
  jobs: (finished = false) => request("GET", `/api/jobs?finished=${finished}`),
  editJob: (id, changes) => request("PATCH", `/api/jobs/${enc(id)}`, changes),
  cancelJob: (id, confirm = false) => request("DELETE", `/api/jobs/${enc(id)}?confirm=${confirm}`),
  moveJob: (id, before) => request("POST", `/api/jobs/${enc(id)}/move`, { before }),
  requeueJob: (id) => request("POST", `/api/jobs/${enc(id)}/requeue`),
  why: (id) => request("GET", `/api/jobs/${enc(id)}/why`),
  attempts: (id) => request("GET", `/api/jobs/${enc(id)}/attempts`),
  queue: () => request("GET", "/api/queue"),
  pauseQueue: (paused) => request("POST", "/api/queue", { paused }),
  gates: () => request("GET", "/api/gates"),
  clearPlate: (id, verdict, cause = "") => request("POST", `${printer(id)}/clear`, { verdict, cause }),
  hold: (id, reason) => request("POST", `${printer(id)}/hold`, { reason }),
  release: (id) => request("POST", `${printer(id)}/release`),
  // The ledger: history, statistics, temperatures (query: an object of filters).
  // The printer page: its macros, and Mainsail/Fluidd on its host.
  macros: (id) => request("GET", `${printer(id)}/macros`),
  printObjects: (id) => request("GET", `${printer(id)}/objects`),
  webUi: (id) => request("GET", `${printer(id)}/web_ui`),
  webcams: (id) => request("GET", `${printer(id)}/webcams`),
  discover: (seconds) => request("GET", `/api/discovery?seconds=${seconds}`),
  temperatures: (id, minutes) => request("GET", `${printer(id)}/temperatures?minutes=${minutes}`),
  history: (query) => request("GET", `/api/history?${queryString(query)}`),
  historyCsvUrl: (query) => `/api/history.csv?${queryString(query)}`,
  stats: (query) => request("GET", `/api/stats?${queryString(query)}`),
  audit: (query) => request("GET", `/api/audit?${queryString(query)}`),
  // Notifications: channels, a test message, the delivery log, noise control, event kinds.
  notifyChannels: () => request("GET", "/api/notifications/channels"),
  addNotifyChannel: (body) => request("POST", "/api/notifications/channels", body),
  updateNotifyChannel: (id, body) => request("PATCH", `/api/notifications/channels/${enc(id)}`, body),
  removeNotifyChannel: (id) => request("DELETE", `/api/notifications/channels/${enc(id)}`),
  testNotifyChannel: (id) => request("POST", `/api/notifications/channels/${enc(id)}/test`),
  notifyDeliveries: (query) => request("GET", `/api/notifications/deliveries?${queryString(query)}`),
  notifySettings: () => request("GET", "/api/notifications/settings"),
  saveNotifySettings: (body) => request("PUT", "/api/notifications/settings", body),
  notifyKinds: () => request("GET", "/api/notifications/kinds"),
};

/** "a=1&b=x" from an object; empty values left out. */
export function queryString(query) {
  const params = new URLSearchParams();
  for (const [key, value] of Object.entries(query || {})) {
    if (value !== undefined && value !== null && value !== "") params.set(key, String(value));
  }
  return params.toString();
}

/**
 * Upload a G-code file with XMLHttpRequest (fetch cannot report upload progress).
 * onProgress(fraction) is called while the bytes go out. Returns {promise, abort}.
 * @param {string} id
 * @param {File} file
 * @param {{start?: boolean, confirm?: boolean, onProgress?: (fraction: number) => void}} [options]
 * @returns {Upload}
 */
export function upload(id, file, { start = false, confirm = false, onProgress } = {}) {
  const form = new FormData();
  form.append("file", file, file.name);
  form.append("start", start ? "true" : "false");
  form.append("confirm", confirm ? "true" : "false");
  return sendForm(`${printer(id)}/files`, form, onProgress);
}

/**
 * Queue a job: its file and options ({quantity, material, tags: [...], ...}; empty values
 * are left out). Returns {promise, abort}, as upload() does.
 * @param {File} file
 * @param {Record<string, unknown>} fields
 * @param {{onProgress?: (fraction: number) => void}} [options]
 * @returns {Upload}
 */
export function uploadJob(file, fields, { onProgress } = {}) {
  const form = new FormData();
  form.append("file", file, file.name);
  for (const [name, value] of Object.entries(fields)) {
    for (const item of Array.isArray(value) ? value : [value]) {
      if (item !== undefined && item !== null && item !== "") form.append(name, String(item));
    }
  }
  return sendForm("/api/jobs", form, onProgress);
}

/**
 * An upload under way: its answer, and a way to stop it.
 * @typedef {{promise: Promise<any>, abort: () => void}} Upload
 */

/**
 * @param {string} path
 * @param {FormData} form
 * @param {((fraction: number) => void) | undefined} onProgress
 * @returns {Upload}
 */
function sendForm(path, form, onProgress) {
  const xhr = new XMLHttpRequest();
  const promise = new Promise((resolve, reject) => {
    xhr.open("POST", path);
    xhr.responseType = "json";
    xhr.upload.addEventListener("progress", (event) => {
      if (event.lengthComputable && onProgress) onProgress(event.loaded / event.total);
    });
    xhr.addEventListener("load", () => {
      const data = xhr.response;
      if (xhr.status === 401) window.dispatchEvent(new CustomEvent("kybercore:unauthorized"));
      if (xhr.status >= 200 && xhr.status < 300) resolve(data);
      else reject(new ApiError(xhr.status, (data && data.error) || { message: `HTTP ${xhr.status}` }));
    });
    xhr.addEventListener("error", () => reject(new ApiError(0, { code: "network", message: t("error.network") })));
    xhr.addEventListener("abort", () => reject(new ApiError(0, { code: "aborted", message: t("upload.aborted") })));
    xhr.send(form);
  });
  return { promise, abort: () => xhr.abort() };
}
