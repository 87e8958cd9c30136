// The job queue as the backend holds it: jobs, printer gates, paused or not. Read over REST,
// and read again whenever a {"type": "queue"} frame arrives on /ws or the socket resyncs
// (several frames in a row cause one read). No DOM here.
import { api } from "./api.js";
import { gates } from "./store.js";

/**
 * A job as GET /api/jobs lists it (JobOut in api/queue_models.py).
 * @typedef {object} Job
 * @property {number} id
 * @property {{sha256: string, name: string, size: number, meta: Record<string, any>}} file
 * @property {number} quantity good copies wanted
 * @property {number} done copies cleared good
 * @property {number} in_flight copies printing, or printed and awaiting a clear
 * @property {number} awaiting_clear of in_flight, the copies printed whose plate awaits a clear
 * @property {number} left copies no printer has yet
 * @property {number} failures
 * @property {number} priority higher runs first
 * @property {number} position
 * @property {"queued" | "blocked" | "done" | "cancelled"} state
 * @property {string} reason why it is blocked or cancelled
 * @property {string | null} not_before
 * @property {{material: string | null, nozzle: number | null, model: string | null, tags: string[],
 *   printer: string | null}} requirements
 * @property {boolean} allow_mismatch
 * @property {number} max_attempts
 * @property {string} created_at
 * @property {string} created_by
 */

/**
 * The queue as a whole, GET /api/queue (QueueState).
 * @typedef {{paused: boolean, queued: number, blocked: number, copies_left: number,
 *   copies_in_flight: number, copies_printing: number, awaiting_clear: string[],
 *   held: string[]}} QueueState
 */

/**
 * A printer's gate, GET /api/gates (GateOut).
 * @typedef {{printer: string, state: "available" | "awaiting_clear" | "held" | "maintenance",
 *   reason: string, since: string, attempt_id: number | null, user: string}} Gate
 */

/**
 * jobs: in dispatch order; state: GET /api/queue; finished: whether done/cancelled are listed.
 * @type {{jobs: Job[], state: QueueState | null, finished: boolean, loaded: boolean, error: unknown}}
 */
export const queue = { jobs: [], state: null, finished: false, loaded: false, error: null };

const listeners = new Set();
let timer = 0;
let loading = null;
let again = false;

/** Be told after every read: fn({gates: Set of printer ids whose gate changed}). */
export function onQueueChange(fn) {
  listeners.add(fn);
}

/** Read the queue again soon; calls within `delay` ms share one read. */
export function refreshQueue(delay = 100) {
  if (timer) return;
  timer = setTimeout(() => {
    timer = 0;
    load();
  }, delay);
}

/** List finished jobs too (or not), and read again. */
export function showFinished(shown) {
  queue.finished = shown;
  refreshQueue(0);
}

async function load() {
  if (loading) {
    again = true; // a change arrived during the read: read once more after it
    return;
  }
  loading = read();
  try {
    await loading;
  } finally {
    loading = null;
    if (again) {
      again = false;
      load();
    }
  }
}

async function read() {
  let changed = new Set();
  try {
    const [jobs, gateMap, state] = await Promise.all([api.jobs(queue.finished), api.gates(), api.queue()]);
    changed = replaceGates(gateMap);
    Object.assign(queue, { jobs, state, loaded: true, error: null });
  } catch (error) {
    queue.error = error;
  }
  for (const fn of listeners) fn({ gates: changed });
}

function gateKey(gate) {
  return gate ? `${gate.state}|${gate.since}|${gate.reason}|${gate.attempt_id}` : "available";
}

/** Replace the gates in store.js; the ids of the printers whose gate changed. */
function replaceGates(gateMap) {
  const changed = new Set();
  for (const [id, gate] of Object.entries(gateMap)) if (gateKey(gates.get(id)) !== gateKey(gate)) changed.add(id);
  for (const id of gates.keys()) if (!(id in gateMap)) changed.add(id);
  gates.clear();
  for (const [id, gate] of Object.entries(gateMap)) gates.set(id, gate);
  return changed;
}

/** A gate's state for a printer ("available" when the queue has no row for it). */
export function gateState(id) {
  return gates.get(id)?.state || "available";
}
