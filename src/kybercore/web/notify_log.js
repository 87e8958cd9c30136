// The delivery log on the Notifications page (GET /api/notifications/deliveries): what was
// sent where, and how it went. Polled every couple of seconds, but only while the page is
// shown and the browser tab visible: a farm's dashboard stays open for days.
import { api } from "./api.js";
import { h, setText } from "./dom.js";
import * as fmt from "./format.js";
import { messageOf, t } from "./i18n.js";
import { printers } from "./store.js";

const POLL_MS = 2000;
const LIMIT = 100;
const COLUMNS = ["time", "channel", "event", "printer", "status", "attempts", "error"];
// Status -> the state colour its pill borrows (see fleet.css data-group).
const GROUP = { delivered: "ready", pending: "printing", retrying: "paused", failed: "error", quiet_hours: "offline" };

let els = null;
let active = false; // the page is shown
let timer = null;
let asked = 0; // answers to older requests are dropped
let shown = ""; // what the table shows, to redraw only on a change
let channels = [];

/** Build the log into `root` (a section). */
export function initLog(root) {
  els = {
    root,
    title: h("h3", { id: "nt-log-title" }),
    channelLabel: h("label", { for: "nt-log-channel" }),
    channel: h("select", { id: "nt-log-channel", onchange: () => refreshLog() }),
    head: h("tr"),
    rows: h("tbody"),
    empty: h("p", { class: "empty", hidden: true }),
  };
  root.setAttribute("aria-labelledby", els.title.id);
  root.append(
    h("header", { class: "nt-section-head" }, els.title, h("span", { class: "toolbar-spacer" }), h("span", { class: "nt-inline-field" }, els.channelLabel, els.channel)),
    h("div", { class: "table-wrap" }, h("table", { class: "fleet-table nt-log" }, h("thead", {}, els.head), els.rows)),
    els.empty,
  );
  document.addEventListener("visibilitychange", () => (document.hidden ? pause() : schedule(0)));
  relabelLog();
}

/** Labels in the current language (and the rows redrawn in it). */
export function relabelLog() {
  if (!els) return;
  setText(els.title, t("nt.log"));
  setText(els.channelLabel, t("nt.log_channel"));
  els.head.replaceChildren(...COLUMNS.map((c) => h("th", { scope: "col" }, t(`nt.log.${c}`))));
  setChannels(channels);
  shown = "";
  refreshLog();
}

/** The channels the log can be narrowed to. */
export function setChannels(list) {
  channels = list;
  if (!els) return;
  const chosen = els.channel.value;
  els.channel.replaceChildren(h("option", { value: "" }, t("nt.log_any_channel")), ...list.map((c) => h("option", { value: String(c.id) }, c.name)));
  els.channel.value = list.some((c) => String(c.id) === chosen) ? chosen : "";
}

/** Start polling (the page is shown). */
export function startLog() {
  active = true;
  schedule(0);
}

/** Stop polling (the page is hidden). */
export function stopLog() {
  active = false;
  pause();
}

/** Load now (after a test message, say), when the page is shown. */
export function refreshLog() {
  if (active) schedule(0);
}

function pause() {
  clearTimeout(timer);
  timer = null;
}

function schedule(ms) {
  if (!active || document.hidden) return;
  clearTimeout(timer);
  timer = setTimeout(poll, ms);
}

async function poll() {
  timer = null;
  await load();
  if (timer === null) schedule(POLL_MS);
}

async function load() {
  const mine = ++asked;
  let items;
  try {
    items = await api.notifyDeliveries({ channel_id: els.channel.value, limit: LIMIT });
  } catch (error) {
    if (mine !== asked) return;
    els.rows.replaceChildren();
    shown = "";
    els.empty.hidden = false;
    setText(els.empty, messageOf(error));
    return;
  }
  if (mine !== asked) return;
  const key = JSON.stringify(items);
  if (key === shown) return;
  shown = key;
  els.rows.replaceChildren(...items.map(row));
  els.empty.hidden = items.length > 0;
  setText(els.empty, t("nt.log_empty"));
}

/** A pending delivery that failed at least once is being retried. */
export function statusOf(delivery) {
  return delivery.status === "pending" && delivery.attempts > 0 ? "retrying" : delivery.status;
}

export function statusText(status) {
  return t(`nt.status.${status}`);
}

function row(item) {
  const status = statusOf(item);
  const printer = item.printer_id ? printers.get(item.printer_id)?.name || item.printer_id : t("nt.log.fleet");
  const error = item.last_error || (item.response_code && status !== "delivered" ? `HTTP ${item.response_code}` : "");
  return h(
    "tr",
    { dataset: { id: String(item.id), channel: String(item.channel_id), status, kind: item.kind } },
    h("td", { class: "c-date" }, fmt.dateTime(Date.parse(item.created_at) / 1000)),
    h("td", {}, item.channel_name),
    h("td", { class: "nt-event" }, item.title),
    h("td", {}, printer),
    h("td", {}, h("span", { class: "pill", dataset: { group: GROUP[status] || "offline" } }, statusText(status))),
    h("td", { class: "c-eta" }, String(item.attempts)),
    h("td", { class: "nt-error", title: error }, error || "—"),
  );
}
