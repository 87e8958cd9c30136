// The ledger's pages, History (#history), Statistics (#stats) and the Audit log (#audit,
// admins): built on first use, refreshed whenever they are shown again, relabelled on a
// language change.
import { initAudit, relabelAudit, showAudit } from "./audit.js";
import { byId } from "./dom.js";
import { onLangChange } from "./i18n.js";
import { initHistory, relabelHistory, showHistory } from "./history.js";
import { hideStats, initStats, relabelStats, showStats } from "./stats.js";
import { subscribe } from "./store.js";

export const LEDGER_PAGES = { "#history": "history", "#stats": "stats", "#audit": "audit" };

let built = false;
let current = null;

/** Show `page` ("history", "stats", "audit") or, for any other page, hide them all. */
export function showLedgerPage(page) {
  const history = byId("history-view");
  const stats = byId("stats-view");
  const audit = byId("audit-view");
  if (!built && (page === "history" || page === "stats" || page === "audit")) {
    initHistory(history);
    initStats(stats);
    initAudit(audit);
    onLangChange(() => {
      relabelHistory();
      relabelStats();
      relabelAudit();
    });
    // Rows name printers by the fleet's names: a page opened from a bookmark may draw
    // before the fleet's first snapshot arrives, so draw them again when one does.
    subscribe((change) => {
      if (!change.full) return;
      relabelHistory();
      relabelStats();
    });
    built = true;
  }
  history.hidden = page !== "history";
  stats.hidden = page !== "stats";
  audit.hidden = page !== "audit";
  if (current === "stats" && page !== "stats") hideStats();
  if (page === current) return;
  current = page;
  if (page === "history") showHistory();
  if (page === "stats") showStats();
  if (page === "audit") showAudit();
}
