// The Audit log view, for admins: who did what to which printer or job, when, from where
// and how it ended (GET /api/audit), newest first, filtered by who, action, target and
// dates, a page at a time. Read-only, as the log itself.
import { api } from "./api.js";
import { h, setText } from "./dom.js";
import * as fmt from "./format.js";
import { t } from "./i18n.js";
import { LedgerTable, localDay } from "./ledger_table.js";

const COLUMNS = ["at", "actor", "action", "target", "params", "outcome", "client"];
const SEARCHES = ["actor", "action", "target"];

let els = null;
let table = null;

/** Build the view into its (empty) section. */
export function initAudit(root) {
  const control = (name, type) => {
    const input = h("input", { id: `audit-${name}`, type, autocomplete: "off" });
    input.addEventListener(type === "search" ? "input" : "change", () => table.reload());
    return input;
  };
  els = {
    actor: control("actor", "search"),
    action: control("action", "search"),
    target: control("target", "search"),
    from: control("from", "date"),
    to: control("to", "date"),
    fromLabel: h("span"),
    toLabel: h("span"),
  };
  table = new LedgerTable(root, {
    id: "audit",
    tableClass: "audit-table",
    keys: "audit",
    columns: COLUMNS,
    filters: [
      ...SEARCHES.map((name) => els[name]),
      h("label", { class: "date-filter" }, els.fromLabel, els.from),
      h("label", { class: "date-filter" }, els.toLabel, els.to),
    ],
    fetch: (limit, offset) =>
      api.audit({
        actor: els.actor.value.trim(),
        action: els.action.value.trim(),
        target: els.target.value.trim(),
        from: localDay(els.from.value, 0),
        to: localDay(els.to.value, 1),
        limit,
        offset,
      }),
    row,
  });
  relabelAudit();
}

/** Show the view: the first time it loads, later it refreshes what it shows. */
export function showAudit() {
  table.load();
}

/** Labels in the current language (and the table redrawn in it). */
export function relabelAudit() {
  if (!els) return;
  setText(els.fromLabel, t("history.from"));
  setText(els.toLabel, t("history.to"));
  for (const name of SEARCHES) {
    els[name].placeholder = t(`audit.${name}`);
    els[name].setAttribute("aria-label", t(`audit.${name}`));
  }
  table.relabel();
}

function row(item) {
  const params = Object.keys(item.params || {}).length ? JSON.stringify(item.params) : "";
  const ok = item.outcome === "ok";
  // Identifiers and parameters as recorded (code, never translated).
  const code = (text, attrs = {}) => h("td", attrs, text ? h("code", { title: text }, text) : "—");
  return h(
    "tr",
    { dataset: { action: item.action, outcome: item.outcome } },
    h("td", { class: "c-date" }, fmt.dateTime(Date.parse(item.at) / 1000)),
    h("td", {}, item.actor, h("span", { class: "muted" }, ` · ${t(`session.role_${item.role}`)}`)),
    code(item.action),
    code(item.target),
    code(params, { class: "c-params" }),
    h("td", {}, h("span", { class: "pill", dataset: { group: ok ? "ready" : "error" } }, ok ? t("audit.ok") : item.outcome)),
    code(item.client),
  );
}
