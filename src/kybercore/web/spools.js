// The spool map (#spools): which Spoolman spool is on which printer, fewest grams first,
// and the printers that show none, with why. Built from the fleet store, like the tiles (the
// same data as GET /api/spools), so it follows every spool change live without polling.
import { pageOf } from "./cards.js";
import { h } from "./dom.js";
import { onLangChange, t } from "./i18n.js";
import { printers, subscribe } from "./store.js";

export const SPOOLS_HASH = "#spools";

/**
 * @typedef {{id: number, name: string, material: string, color_hex: string,
 *   remaining_g: number | null, low: boolean}} Spool as the printer's view carries it
 * @typedef {{id: string, name: string}} Holder
 * @typedef {Spool & {printers: Holder[]}} SpoolRow
 * @typedef {Holder & {spoolman: string}} Without
 */

let root = null;
let shown = false;
/** printer id -> what the map shows of it, to rebuild only when that changed */
let seen = new Map();

/** Show or hide the spool map for the page the router chose. */
export function showSpoolsPage(page) {
  root ||= init(document.getElementById("spools-view"));
  const show = page === "spools";
  root.hidden = !show;
  if (show && !shown) render();
  shown = show;
}

function init(el) {
  subscribe((change) => {
    if (!shown) return;
    // Temperatures change every tick; the map only when a spool, a name or a printer did.
    let dirty = change.full || change.removed.size > 0;
    for (const id of change.changed) dirty = noteOf(id) !== seen.get(id) || dirty;
    if (dirty) render();
  });
  onLangChange(() => shown && render());
  return el;
}

function noteOf(id) {
  const p = printers.get(id);
  return p ? JSON.stringify([p.name, p.spool, p.spoolman]) : "";
}

/**
 * Each active spool once with the printers holding it (the same spool set active on two
 * printers is a mistake to show), fewest grams first; then the printers without a spool.
 * Pure: the same grouping and order as kybercore.core.spools.spool_map.
 * @param {Iterable<any>} views
 * @returns {{spools: SpoolRow[], without: Without[]}}
 */
export function spoolMap(views) {
  /** @type {Map<number, SpoolRow>} */
  const spools = new Map();
  /** @type {Without[]} */
  const without = [];
  for (const view of views) {
    const holder = { id: view.id, name: view.name };
    const spool = view.spool;
    if (!spool || typeof spool.id !== "number") {
      without.push({ ...holder, spoolman: view.spoolman || "unknown" });
      continue;
    }
    const row = spools.get(spool.id) || { ...spool, printers: [] };
    row.printers.push(holder);
    spools.set(spool.id, row);
  }
  const grams = (s) => (typeof s.remaining_g === "number" ? s.remaining_g : Infinity);
  const rows = [...spools.values()].sort((a, b) => grams(a) - grams(b) || a.id - b.id);
  return { spools: rows, without };
}

function render() {
  seen = new Map([...printers.keys()].map((id) => [id, noteOf(id)]));
  const { spools, without } = spoolMap(printers.values());
  const low = spools.filter((s) => s.low).length;
  const summary = [t("spools.summary", { n: spools.length }), low ? t("spools.low_count", { n: low }) : ""].filter(Boolean).join(" · ");
  const head = h("header", { class: "ledger-head" }, h("h2", { id: "spools-title", text: t("spools.title") }), h("p", { class: "muted", text: summary }));
  const parts = [head];
  if (spools.length) parts.push(spoolTable(spools));
  else parts.push(h("p", { class: "empty", text: t("spools.none") }));
  if (without.length) {
    parts.push(
      h("h3", { id: "spools-without", class: "spools-sub", text: t("spools.without") }),
      h("ul", { class: "spools-without", "aria-labelledby": "spools-without" }, ...without.map(withoutItem)),
    );
  }
  root.replaceChildren(...parts);
}

/** @param {SpoolRow[]} spools */
function spoolTable(spools) {
  const cols = ["spool", "material", "left", "printer"];
  return h(
    "div",
    { class: "table-wrap" },
    h(
      "table",
      { class: "fleet-table spools-table", "aria-labelledby": "spools-title" },
      h("thead", {}, h("tr", {}, ...cols.map((c) => h("th", { scope: "col", text: t(`spools.col.${c}`) })))),
      h("tbody", {}, ...spools.map(spoolRow)),
    ),
  );
}

/** @param {SpoolRow} s */
function spoolRow(s) {
  const swatch = h("span", { class: "swatch", role: "img", "aria-label": s.color_hex ? t("spools.colour", { hex: s.color_hex.toUpperCase() }) : t("spools.no_colour") });
  if (s.color_hex) swatch.style.background = `#${s.color_hex}`; // CSSOM: the CSP allows it
  const grams = typeof s.remaining_g === "number" ? t("spools.grams", { g: Math.round(s.remaining_g) }) : t("spools.unknown_weight");
  const left = h("td", { class: "num" }, h("span", { text: grams }));
  if (s.low) left.append(" ", h("span", { class: "spool-low", text: t("spools.low") }));
  const holders = s.printers.map((p) => h("a", { class: "name-link", href: pageOf(p.id), text: p.name || p.id }));
  const on = h("td", { class: "spool-printers" }, ...holders);
  if (s.printers.length > 1) on.append(h("span", { class: "spool-low", text: t("spools.shared", { n: s.printers.length }) }));
  return h(
    "tr",
    { dataset: { spool: String(s.id) }, class: s.low ? "is-low" : "" },
    h("td", { class: "spool-name" }, swatch, h("span", { class: "name", text: s.name || t("spool.title", { id: s.id }) }), h("span", { class: "muted", text: ` #${s.id}` })),
    h("td", { text: s.material || "—" }),
    left,
    on,
  );
}

/** @param {Without} p */
function withoutItem(p) {
  const why = ["absent", "none", "unreachable"].includes(p.spoolman) ? p.spoolman : "unknown";
  return h("li", { dataset: { id: p.id } }, h("a", { class: "name-link", href: pageOf(p.id), text: p.name || p.id }), h("span", { class: "muted", text: t(`spools.why.${why}`) }));
}
