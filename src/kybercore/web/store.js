// Fleet state: the printers as the backend publishes them over /ws, plus pure helpers
// (status, filtering, sorting) that the views share. No DOM here.

/** id -> printer view, exactly as the backend sent it (deltas merged in). */
export const printers = new Map();

/**
 * id -> the printer's plate gate in the job queue (queue_data.js keeps it); none: available.
 * @type {Map<string, import("./queue_data.js").Gate>}
 */
export const gates = new Map();

/** The filter value that shows the printers whose plate awaits a clear (not a status group). */
export const AWAITING = "awaiting_clear";

const listeners = new Set();
/** @type {Set<string> | null} the printers the server sends in full (null: all of them) */
let detail = null;
let seq = null;
let skew = 0; // server clock minus browser clock, in seconds (from heartbeats)

/** Be told about every change: {full, changed: Set, removed: Set, transitions: []}. */
export function subscribe(fn) {
  listeners.add(fn);
  return () => listeners.delete(fn);
}

function emit(change) {
  for (const fn of listeners) fn(change);
}

/**
 * Replace the whole state (first frame, and whenever the server resyncs us). With a view
 * (see live.js watchView), `printers` holds slim summaries and `full` the views in it.
 */
export function applySnapshot(frame) {
  const removed = new Set(printers.keys());
  printers.clear();
  for (const view of [...(frame.printers || []), ...(frame.full || [])]) {
    printers.set(view.id, view);
    removed.delete(view.id);
  }
  seq = frame.seq;
  emit({ full: true, changed: new Set(printers.keys()), removed, transitions: [] });
}

const NEW = Symbol("new printer"); // no state before: no transition

/** Merge a delta; false when a frame is missing (the caller resyncs). */
export function applyDelta(frame) {
  if (seq !== null && frame.seq !== seq + 1) return false;
  seq = frame.seq;
  const changed = new Set();
  const transitions = [];
  const before = new Map();
  // Slim patches of every changed printer, then full patches of those in view (if any).
  for (const patches of [frame.printers || {}, frame.full || {}]) {
    for (const [id, patch] of Object.entries(patches)) {
      const current = printers.get(id);
      if (!before.has(id)) before.set(id, current === undefined ? NEW : current.job?.state);
      if (current === undefined) printers.set(id, patch);
      else merge(current, patch);
      changed.add(id);
    }
  }
  for (const [id, from] of before) {
    const to = printers.get(id)?.job?.state;
    if (from !== NEW && from !== to) transitions.push({ id, from, to });
  }
  const removed = new Set(frame.removed || []);
  for (const id of removed) printers.delete(id);
  if (changed.size || removed.size) emit({ full: false, changed, removed, transitions });
  return true;
}

/** Full views of printers that came into view: they replace the summaries we had. */
export function applyViews(frame) {
  const changed = new Set();
  for (const view of frame.printers || []) {
    printers.set(view.id, view);
    changed.add(view.id);
  }
  if (changed.size) emit({ full: false, changed, removed: new Set(), transitions: [] });
}

/**
 * Which printers the server sends in full from now on (null: all). The others carry only
 * their summary: their heaters and `updated_at` are as last seen in full, so no age is
 * judged from them.
 * @param {string[] | null} ids
 */
export function setDetail(ids) {
  detail = ids === null ? null : new Set(ids);
}

/** Forget the sequence (the socket closed); the next snapshot starts afresh. */
export function resetSequence() {
  seq = null;
}

/** Deep merge: objects key by key, arrays and scalars replaced. */
export function merge(target, patch) {
  for (const [key, value] of Object.entries(patch)) {
    const old = target[key];
    if (isObject(value) && isObject(old)) merge(old, value);
    else target[key] = value;
  }
  return target;
}

function isObject(value) {
  return value !== null && typeof value === "object" && !Array.isArray(value);
}

export function noteServerTime(serverTime) {
  if (typeof serverTime === "number") skew = serverTime - Date.now() / 1000;
}

/** Now, in the server's clock (unix seconds). */
export function serverNow() {
  return Date.now() / 1000 + skew;
}

// -- derived state -------------------------------------------------------------------------

export const GROUPS = ["printing", "paused", "error", "done", "ready", "offline"];

/** What the tile's color and the state filter use: {group, key (an i18n key)}. */
export function statusOf(p) {
  const conn = p.connection;
  if (conn === "disabled") return { group: "offline", key: "status.disabled" };
  if (conn === "auth_failed") return { group: "error", key: "status.auth_failed" };
  if (conn === "connecting") return { group: "offline", key: "status.connecting" };
  if (conn !== "online") return { group: "offline", key: "status.offline" };
  const klippy = p.klippy_state;
  if (klippy === "shutdown") return { group: "error", key: "status.shutdown" };
  if (klippy === "error") return { group: "error", key: "status.klippy_error" };
  if (klippy === "startup") return { group: "offline", key: "status.startup" };
  if (klippy !== "ready") return { group: "offline", key: "status.klippy_disconnected" };
  const job = p.job?.state;
  if (job === "printing") return { group: "printing", key: "status.printing" };
  if (job === "paused") return { group: "paused", key: "status.paused" };
  if (job === "error") return { group: "error", key: "status.print_error" };
  // A finished or cancelled print may still be on the plate: not "ready" until cleared.
  if (job === "complete") return { group: "done", key: "status.complete" };
  if (job === "cancelled") return { group: "done", key: "status.cancelled" };
  return { group: "ready", key: "status.ready" };
}

export const STALE_SECONDS = 10;

/**
 * Seconds since the last message from Moonraker when that matters, else null.
 * An idle printer whose session is up sends nothing while nothing changes, so its age
 * means nothing; it does for a printer that is not online, or that is printing (whose
 * progress and durations change all the time).
 */
export function staleAge(p, now = serverNow()) {
  if (!p.updated_at || (detail !== null && !detail.has(p.id))) return null;
  const age = now - p.updated_at;
  if (age < STALE_SECONDS) return null;
  const busy = p.job?.state === "printing" || p.job?.state === "paused";
  return p.connection !== "online" || busy ? age : null;
}

/** Whether a printer passes the filters {q, state, tag, location}. */
export function matches(p, f) {
  if (f.state === AWAITING) {
    if (gates.get(p.id)?.state !== AWAITING) return false;
  } else if (f.state && statusOf(p).group !== f.state) return false;
  if (f.tag && !(p.tags || []).includes(f.tag)) return false;
  if (f.location && p.location !== f.location) return false;
  if (f.q) {
    const hay = [p.id, p.name, p.model, p.location, p.job?.filename, ...(p.tags || [])]
      .join(" ")
      .toLowerCase();
    for (const word of f.q.toLowerCase().split(/\s+/)) {
      if (word && !hay.includes(word)) return false;
    }
  }
  return true;
}

const GROUP_ORDER = { error: 0, paused: 1, printing: 2, done: 3, ready: 4, offline: 5 };
const byName = (a, b) => a.name.localeCompare(b.name, undefined, { numeric: true }) || a.id.localeCompare(b.id);

/** A comparator for the sort select. */
export function comparator(sort) {
  switch (sort) {
    case "status":
      return (a, b) => GROUP_ORDER[statusOf(a).group] - GROUP_ORDER[statusOf(b).group] || byName(a, b);
    case "progress":
      return (a, b) => (b.job?.progress || 0) - (a.job?.progress || 0) || byName(a, b);
    case "eta":
      return (a, b) => etaKey(a) - etaKey(b) || byName(a, b);
    case "location":
      return (a, b) => (a.location || "").localeCompare(b.location || "") || byName(a, b);
    default:
      return byName;
  }
}

function etaKey(p) {
  const eta = p.job?.eta_seconds;
  return typeof eta === "number" ? eta : Number.POSITIVE_INFINITY;
}

/** The values the sort and filters read: when they change, the order may change. */
export function orderKey(p) {
  const s = statusOf(p);
  return `${s.group}|${p.name}|${p.location}|${(p.tags || []).join(",")}|${p.job?.filename}|${Math.round((p.job?.progress || 0) * 100)}|${p.job?.eta_seconds}`;
}

/** Every distinct tag, location and site, sorted (for the filter menus and the form). */
export function facets() {
  const tags = new Set();
  const locations = new Set();
  const sites = new Set();
  for (const p of printers.values()) {
    for (const tag of p.tags || []) tags.add(tag);
    if (p.location) locations.add(p.location);
    if (p.site) sites.add(p.site);
  }
  const sort = (set) => [...set].sort((a, b) => a.localeCompare(b));
  return { tags: sort(tags), locations: sort(locations), sites: sort(sites) };
}
