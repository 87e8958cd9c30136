// The one WebSocket to the backend: snapshot, deltas and events; reconnects by itself with
// backoff and resyncs from the next snapshot. Status goes to onStatus for the banner.
// Frames arrive as binary UTF-8 JSON (the server encodes each once for every client); text
// frames are read too.
import { applyDelta, applySnapshot, applyViews, noteServerTime, resetSequence, setDetail } from "./store.js";

const BACKOFF = [500, 1000, 2000, 3000, 5000];
const SILENCE_MS = 25000; // heartbeats come every 10 s when idle
// A view named in the URL makes the first snapshot the view's; a longer list (a filter of
// hundreds of printers) is sent once open instead: servers cap the request line at ~8 kB.
const MAX_VIEW_IN_URL = 4000;

let socket = null;
let attempt = 0;
let consoleIds = [];
/** @type {string[] | null} the printers to get in full (null: all of them) */
let viewIds = null;
const decoder = new TextDecoder();
let watchdog = null;
let retryTimer = null;
/** @type {{onEvent: (frame: any) => void, onStatus: (status: any) => void}} */
let handlers = { onEvent: () => {}, onStatus: () => {} };

/** Start the connection. onStatus({state: "connecting"|"live"|"down", retryAt, since}). */
export function startLive(options) {
  handlers = { ...handlers, ...options };
  connect();
}

/** Ask for the G-code responses of these printers (kept across reconnects). */
export function watchConsole(ids) {
  consoleIds = [...ids];
  send({ type: "console", printers: consoleIds });
}

/**
 * Get full views of these printers only, slim summaries (state, progress, ETA, alarms) of
 * the others; null: every printer in full. Kept across reconnects.
 * @param {string[] | null} ids
 */
export function watchView(ids) {
  viewIds = ids === null ? null : [...ids];
  setDetail(viewIds);
  send({ type: "view", printers: viewIds });
}

/** Reconnect now instead of waiting for the backoff. */
export function reconnectNow() {
  if (socket) return;
  clearTimeout(retryTimer);
  connect();
}

/** /ws, with the view when it is known and short (a reconnect, mostly). */
function socketUrl() {
  const base = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`;
  if (viewIds === null) return base;
  const query = `?view=${encodeURIComponent(viewIds.join(","))}`;
  return query.length <= MAX_VIEW_IN_URL ? base + query : base;
}

function send(frame) {
  if (socket && socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(frame));
}

function connect() {
  retryTimer = null;
  handlers.onStatus({ state: "connecting", attempt });
  const ws = new WebSocket(socketUrl());
  ws.binaryType = "arraybuffer";
  socket = ws;
  ws.addEventListener("open", () => {
    if (consoleIds.length) send({ type: "console", printers: consoleIds });
    if (viewIds !== null) send({ type: "view", printers: viewIds });
    armWatchdog();
  });
  ws.addEventListener("message", (event) => {
    if (ws !== socket) return;
    armWatchdog();
    let frame;
    try {
      frame = JSON.parse(typeof event.data === "string" ? event.data : decoder.decode(event.data));
    } catch {
      return;
    }
    receive(frame, ws);
  });
  ws.addEventListener("close", () => lost(ws));
}

/** The socket is gone (closed, silent, or out of step): show it, and retry with backoff. */
function lost(ws) {
  if (ws !== socket) return;
  socket = null;
  clearTimeout(watchdog);
  resetSequence();
  if (ws.readyState === WebSocket.CONNECTING || ws.readyState === WebSocket.OPEN) ws.close();
  const delay = BACKOFF[Math.min(attempt, BACKOFF.length - 1)] * (0.8 + Math.random() * 0.4);
  attempt += 1;
  handlers.onStatus({ state: "down", retryAt: Date.now() + delay, attempt });
  retryTimer = setTimeout(connect, delay);
}

function receive(frame, ws) {
  switch (frame.type) {
    case "snapshot":
      attempt = 0;
      applySnapshot(frame);
      handlers.onStatus({ state: "live" });
      break;
    case "delta":
      if (!applyDelta(frame)) lost(ws); // a frame went missing: resync from a snapshot
      break;
    case "views":
      applyViews(frame);
      break;
    case "heartbeat":
      noteServerTime(frame.time);
      break;
    default:
      handlers.onEvent(frame);
  }
}

function armWatchdog() {
  clearTimeout(watchdog);
  const ws = socket;
  watchdog = setTimeout(() => lost(ws), SILENCE_MS);
}
