// "Utilisation today" in the header: the share of the fleet's observed time since local
// midnight spent printing, from the ledger's statistics (GET /api/stats, per printer). The
// fleet's figure is the mean over printers with a timeline today. Refreshed every minute
// while the page is visible.
import { api } from "./api.js";
import { setText } from "./dom.js";
import { t } from "./i18n.js";
import { subscribe } from "./store.js";

const EVERY_MS = 60000;
let el = null;
let value = null; // 0..1, or null before the first answer (or with no timeline today)
let timer = null;

/** Show the figure in `element` and keep it fresh, from the first live snapshot on (the
 * page may be waiting for a login before that). */
export function initUtilisation(element) {
  el = element;
  let live = false;
  subscribe((change) => {
    if (!change.full) return;
    live = true;
    refresh();
  });
  document.addEventListener("visibilitychange", () => {
    if (live && !document.hidden) refresh();
  });
}

/** Redraw in the current language. */
export function relabelUtilisation() {
  draw();
}

async function refresh() {
  clearTimeout(timer);
  if (document.hidden) return;
  const midnight = new Date();
  midnight.setHours(0, 0, 0, 0);
  try {
    const answer = await api.stats({ group_by: "printer", from: midnight.toISOString(), to: new Date().toISOString() });
    const shares = answer.rows.map((row) => row.utilisation).filter((u) => typeof u === "number");
    value = shares.length ? shares.reduce((a, b) => a + b, 0) / shares.length : null;
  } catch {
    value = null; // a viewer without the ledger, a restart: no figure rather than a wrong one
  }
  draw();
  timer = setTimeout(refresh, EVERY_MS);
}

function draw() {
  if (!el) return;
  el.hidden = value === null;
  setText(el, value === null ? "" : t("summary.utilisation", { pct: Math.round(value * 100) }));
  el.title = t("summary.utilisation_help");
}
