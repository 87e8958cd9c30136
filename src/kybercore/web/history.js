// The History view: every job the farm printed, from the ledger (GET /api/history),
// filtered by printer, outcome, file, user and dates, a page at a time, and the same
// selection as a CSV file (GET /api/history.csv).
import { ApiError, api } from "./api.js";
import { h, setText } from "./dom.js";
import * as fmt from "./format.js";
import { messageOf, t } from "./i18n.js";
import { printers } from "./store.js";

const PAGE = 50;
const OUTCOMES = ["completed", "cancelled", "error", "klippy_shutdown", "in_progress"];
// Outcome -> the state colour it borrows (see fleet.css data-group).
const GROUP = { completed: "ready", cancelled: "paused", error: "error", klippy_shutdown: "error", in_progress: "printing" };
const COLUMNS = ["printer", "file", "status", "started", "ended", "print", "filament", "verdict", "user"];

let els = null;
let offset = 0;
let loaded = false;
let asked = 0; // answers to older requests are dropped

/** Build the view into its (empty) section. */
export function initHistory(root) {
  const filter = (id, control) => {
    control.id = id;
    control.addEventListener(control.type === "search" ? "input" : "change", () => reload());
    return control;
  };
  els = {
    root,
    title: h("h2", { id: "history-title" }),
    summary: h("p", { class: "muted", "aria-live": "polite" }),
    csv: h("a", { class: "btn", id: "history-csv", download: "kybercore-history.csv" }),
    printer: filter("history-printer", h("select")),
    status: filter("history-status", h("select")),
    file: filter("history-file", h("input", { type: "search", autocomplete: "off" })),
    user: filter("history-user", h("input", { type: "search", autocomplete: "off" })),
    from: filter("history-from", h("input", { type: "date" })),
    to: filter("history-to", h("input", { type: "date" })),
    fromLabel: h("span"),
    toLabel: h("span"),
    head: h("tr"),
    rows: h("tbody"),
    empty: h("p", { class: "empty", hidden: true }),
    prev: h("button", { type: "button", class: "btn small", onclick: () => page(-1) }),
    next: h("button", { type: "button", class: "btn small", onclick: () => page(1) }),
    pageText: h("span", { class: "muted" }),
  };
  root.setAttribute("aria-labelledby", "history-title");
  root.append(
    h("header", { class: "ledger-head" }, els.title, els.summary, h("span", { class: "toolbar-spacer" }), els.csv),
    h(
      "div",
      { class: "toolbar ledger-filters" },
      els.printer,
      els.status,
      els.file,
      els.user,
      h("label", { class: "date-filter" }, els.fromLabel, els.from),
      h("label", { class: "date-filter" }, els.toLabel, els.to),
    ),
    h("div", { class: "table-wrap" }, h("table", { class: "fleet-table ledger-table" }, h("thead", {}, els.head), els.rows)),
    els.empty,
    h("nav", { class: "pager" }, els.prev, els.pageText, els.next),
  );
  relabelHistory();
}

/** Show the view: the first time it loads, later it refreshes what it shows. */
export function showHistory() {
  fillPrinters();
  load();
}

/** Labels in the current language (and the table redrawn in it). */
export function relabelHistory() {
  if (!els) return;
  setText(els.title, t("history.title"));
  setText(els.csv, t("history.csv"));
  setText(els.fromLabel, t("history.from"));
  setText(els.toLabel, t("history.to"));
  setText(els.prev, t("history.prev"));
  setText(els.next, t("history.next"));
  els.file.placeholder = t("history.file");
  els.user.placeholder = t("history.user");
  for (const [control, key] of [[els.printer, "history.printer"], [els.status, "history.status"], [els.file, "history.file"], [els.user, "history.user"]]) {
    control.setAttribute("aria-label", t(key));
  }
  const status = els.status.value;
  els.status.replaceChildren(
    h("option", { value: "" }, t("history.any_status")),
    ...OUTCOMES.map((o) => h("option", { value: o }, outcomeText(o))),
  );
  els.status.value = status;
  els.head.replaceChildren(...COLUMNS.map((c) => h("th", { scope: "col" }, t(`history.col.${c}`))));
  fillPrinters();
  if (loaded) load();
}

function fillPrinters() {
  const chosen = els.printer.value;
  const known = [...printers.values()].sort((a, b) => a.name.localeCompare(b.name));
  els.printer.replaceChildren(
    h("option", { value: "" }, t("history.any_printer")),
    ...known.map((p) => h("option", { value: p.id }, p.name)),
  );
  if (chosen && !printers.has(chosen)) els.printer.append(h("option", { value: chosen }, chosen));
  els.printer.value = chosen;
}

/** The filters as the API takes them; dates are whole local days. */
function filters() {
  const day = (value, plus) => {
    if (!value) return "";
    const [y, m, d] = value.split("-").map(Number);
    return new Date(y, m - 1, d + plus).toISOString();
  };
  return {
    printer: els.printer.value,
    status: els.status.value,
    file: els.file.value.trim(),
    user: els.user.value.trim(),
    from: day(els.from.value, 0),
    to: day(els.to.value, 1),
  };
}

function reload() {
  offset = 0;
  load();
}

function page(step) {
  offset = Math.max(0, offset + step * PAGE);
  load();
}

async function load() {
  const query = filters();
  els.csv.href = api.historyCsvUrl(query);
  const mine = ++asked;
  els.root.setAttribute("aria-busy", "true");
  let answer;
  try {
    answer = await api.history({ ...query, limit: PAGE, offset });
  } catch (error) {
    if (mine !== asked) return;
    els.root.removeAttribute("aria-busy");
    els.rows.replaceChildren();
    els.empty.hidden = false;
    setText(els.empty, error instanceof ApiError ? messageOf(error) : t("error.unknown"));
    return;
  }
  if (mine !== asked) return;
  loaded = true;
  els.root.removeAttribute("aria-busy");
  render(answer);
}

function render({ total, items }) {
  els.rows.replaceChildren(...items.map(row));
  els.empty.hidden = items.length > 0;
  setText(els.empty, t("history.empty"));
  const first = items.length ? offset + 1 : 0;
  setText(els.summary, t(total === 1 ? "history.summary_one" : "history.summary", { total }));
  setText(els.pageText, t("history.page", { first, last: offset + items.length, total }));
  els.prev.disabled = offset === 0;
  els.next.disabled = offset + items.length >= total;
  els.root.dataset.total = String(total);
}

function row(item) {
  const name = printers.get(item.printer)?.name || item.printer;
  const seconds = (iso) => (iso ? Date.parse(iso) / 1000 : null);
  const filament = item.filament_g ? `${item.filament_g.toFixed(1)} g` : `${((item.filament_mm || 0) / 1000).toFixed(2)} m`;
  const verdict = item.verdict ? t(`verdict.${item.verdict}`) + (item.cause ? ` · ${item.cause}` : "") : "—";
  return h(
    "tr",
    { dataset: { printer: item.printer, status: item.status } },
    h("td", { class: "c-name" }, name),
    // Moonraker may record a job without its file (a print it saw only end): say so.
    item.filename
      ? h("td", { class: "c-file", title: item.filename }, fmt.baseName(item.filename))
      : h("td", { class: "c-file", title: t("history.no_file") }, "—"),
    h("td", {}, h("span", { class: "pill", dataset: { group: GROUP[item.status] || "offline" } }, outcomeText(item.status))),
    h("td", { class: "c-date" }, fmt.dateTime(seconds(item.started_at))),
    h("td", { class: "c-date" }, fmt.dateTime(seconds(item.ended_at))),
    h("td", { class: "c-eta" }, fmt.duration(item.print_seconds)),
    h("td", { class: "c-eta" }, filament),
    h("td", {}, verdict),
    h("td", {}, item.user || "—"),
  );
}

/** A job's outcome in words; Moonraker's own name for one this page does not know. */
export function outcomeText(status) {
  const key = `outcome.${status}`;
  const text = t(key);
  return text === key ? status : text;
}
