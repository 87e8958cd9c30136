// The ledger's pages, History (#history) and Statistics (#stats): built on first use,
// refreshed whenever they are shown again, relabelled on a language change.
import { byId } from "./dom.js";
import { onLangChange } from "./i18n.js";
import { initHistory, relabelHistory, showHistory } from "./history.js";
import { hideStats, initStats, relabelStats, showStats } from "./stats.js";

export const LEDGER_PAGES = { "#history": "history", "#stats": "stats" };

let built = false;
let current = null;

/** Show `page` ("history", "stats") or, for any other page, hide both. */
export function showLedgerPage(page) {
  const history = byId("history-view");
  const stats = byId("stats-view");
  if (!built && (page === "history" || page === "stats")) {
    initHistory(history);
    initStats(stats);
    onLangChange(() => {
      relabelHistory();
      relabelStats();
    });
    built = true;
  }
  history.hidden = page !== "history";
  stats.hidden = page !== "stats";
  if (current === "stats" && page !== "stats") hideStats();
  if (page === current) return;
  current = page;
  if (page === "history") showHistory();
  if (page === "stats") showStats();
}
