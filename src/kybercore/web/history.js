// The History view: every job the farm printed, from the ledger (GET /api/history),
// filtered by printer, outcome, file, user and dates, a page at a time, and the same
// selection as a CSV file (GET /api/history.csv).
import { api } from "./api.js";
import { h, setText } from "./dom.js";
import * as fmt from "./format.js";
import { t } from "./i18n.js";
import { LedgerTable, localDay } from "./ledger_table.js";
import { printers } from "./store.js";

const OUTCOMES = ["completed", "cancelled", "error", "klippy_shutdown", "in_progress"];
// Outcome -> the state colour it borrows (see fleet.css data-group).
const GROUP = { completed: "ready", cancelled: "paused", error: "error", klippy_shutdown: "error", in_progress: "printing" };
const COLUMNS = ["printer", "file", "status", "started", "ended", "print", "filament", "verdict", "user"];

let els = null;
let table = null;

/** Build the view into its (empty) section. */
export function initHistory(root) {
  const filter = (id, control) => {
    control.id = id;
    control.addEventListener(control.type === "search" ? "input" : "change", () => table.reload());
    return control;
  };
  els = {
    csv: h("a", { class: "btn", id: "history-csv", download: "kybercore-history.csv" }),
    printer: filter("history-printer", h("select")),
    status: filter("history-status", h("select")),
    file: filter("history-file", h("input", { type: "search", autocomplete: "off" })),
    user: filter("history-user", h("input", { type: "search", autocomplete: "off" })),
    from: filter("history-from", h("input", { type: "date" })),
    to: filter("history-to", h("input", { type: "date" })),
    fromLabel: h("span"),
    toLabel: h("span"),
  };
  table = new LedgerTable(root, {
    id: "history",
    keys: "history",
    columns: COLUMNS,
    actions: [els.csv],
    filters: [
      els.printer,
      els.status,
      els.file,
      els.user,
      h("label", { class: "date-filter" }, els.fromLabel, els.from),
      h("label", { class: "date-filter" }, els.toLabel, els.to),
    ],
    fetch: (limit, offset) => {
      const query = filters();
      els.csv.href = api.historyCsvUrl(query);
      return api.history({ ...query, limit, offset });
    },
    row,
  });
  relabelHistory();
}

/** Show the view: the first time it loads, later it refreshes what it shows. */
export function showHistory() {
  fillPrinters();
  table.load();
}

/** Labels in the current language (and the table redrawn in it). */
export function relabelHistory() {
  if (!els) return;
  setText(els.csv, t("history.csv"));
  setText(els.fromLabel, t("history.from"));
  setText(els.toLabel, t("history.to"));
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
  fillPrinters();
  table.relabel();
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
  return {
    printer: els.printer.value,
    status: els.status.value,
    file: els.file.value.trim(),
    user: els.user.value.trim(),
    from: localDay(els.from.value, 0),
    to: localDay(els.to.value, 1),
  };
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
