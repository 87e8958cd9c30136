// KyberCore's dashboard: wires the live connection, the overview, actions, bulk actions,
// the printer drawer (files, console), printer forms, language and theme together.
import { initActions, onCardButton } from "./actions.js";
import { alertOperator, initAlerts } from "./alerts.js";
import { CAMERAS_HASH, showCamerasPage } from "./cameras.js";
import { initBulk, updateBulkBar } from "./bulk.js";
import { toast } from "./dialogs.js";
import { byId, setText } from "./dom.js";
import { initDensity } from "./density.js";
import { findPrinters } from "./discovery.js";
import { initDrawer, onConsoleFrame, openDrawer, relabelDrawer } from "./drawer.js";
import { onFilesChanged } from "./files.js";
import * as fmt from "./format.js";
import { getLang, loadLang, onLangChange, setLang, t, translateStatic } from "./i18n.js";
import { reconnectNow, startLive } from "./live.js";
import { initOverview, rebuild, setMode } from "./overview.js";
import { printerDialog, removePrinter } from "./printer_form.js";
import { SPOOLS_HASH, showSpoolsPage } from "./spools.js";
import { printerOfHash, showPrinterPage } from "./printer_page.js";
import { LEDGER_PAGES, showLedgerPage } from "./ledger_views.js";
import { NOTIFY_HASH, showNotificationsPage } from "./notifications.js";
import { initQueue, relabelQueue } from "./queue.js";
import { refreshQueue } from "./queue_data.js";
import { can, currentSession, loadSession, login, logout, needsLogin, onSessionChange } from "./session.js";
import { printers, subscribe } from "./store.js";
import { uploadDialog } from "./uploads.js";
import { initUtilisation, relabelUtilisation } from "./utilisation.js";
import { showNow } from "./watch.js";

const $ = byId;
let lastData = null; // when the last frame changed something (for the banner)

function initTheme() {
  const button = $("theme");
  const root = document.documentElement;
  const label = () => {
    const dark = root.dataset.theme === "dark";
    const text = t(dark ? "theme.to_light" : "theme.to_dark");
    button.setAttribute("aria-label", text);
    button.title = text;
    button.replaceChildren(iconFor(dark ? "sun" : "moon"));
  };
  button.addEventListener("click", () => {
    root.dataset.theme = root.dataset.theme === "dark" ? "light" : "dark";
    try {
      localStorage.setItem("kybercore.theme", root.dataset.theme);
    } catch {
      // private mode: the choice lasts for this page only
    }
    label();
  });
  onLangChange(label);
  label();
}

function iconFor(name) {
  const paths = {
    sun: "M12 8a4 4 0 1 0 0 8 4 4 0 0 0 0-8zM12 2v2M12 20v2M2 12h2M20 12h2M5 5l1.5 1.5M17.5 17.5L19 19M5 19l1.5-1.5M17.5 6.5L19 5",
    moon: "M20 14.5A8 8 0 0 1 9.5 4 8 8 0 1 0 20 14.5z",
  };
  const svg = document.createElementNS("http://www.w3.org/2000/svg", "svg");
  svg.setAttribute("viewBox", "0 0 24 24");
  svg.setAttribute("aria-hidden", "true");
  svg.classList.add("icon");
  const path = document.createElementNS("http://www.w3.org/2000/svg", "path");
  path.setAttribute("d", paths[name]);
  svg.append(path);
  return svg;
}

/** The live indicator and the banner shown while the backend is unreachable. */
function liveStatusHandler() {
  const banner = $("banner");
  const indicator = $("live");
  let status = { state: "connecting" };
  let wasDown = false;
  const render = () => {
    const state = status.state;
    indicator.dataset.state = state === "live" ? "live" : wasDown ? "down" : "connecting";
    setText(indicator.querySelector(".live-text"), t(state === "live" ? "live.live" : wasDown ? "live.down" : "live.connecting"));
    const show = state !== "live" && wasDown;
    banner.hidden = !show;
    document.body.classList.toggle("is-offline", show);
    if (!show) return;
    const seconds = status.retryAt ? Math.max(0, Math.ceil((status.retryAt - Date.now()) / 1000)) : 0;
    setText($("banner-retry"), state === "down" && seconds > 0 ? t("banner.retry_in", { s: seconds }) : t("banner.reconnecting"));
    setText($("banner-since"), lastData ? t("banner.since", { time: new Date(lastData).toLocaleTimeString(getLang()) }) : "");
  };
  setInterval(() => status.state === "down" && render(), 500);
  onLangChange(render);
  $("banner-retry-now").addEventListener("click", reconnectNow);
  return (next) => {
    status = next;
    if (next.state !== "live") brokerBanner.forget();
    if (next.state === "down") {
      wasDown = true;
      checkAccess();
    }
    if (next.state === "live") wasDown = false;
    render();
  };
}

/**
 * The banner shown while this KyberCore front is cut off from its NATS broker: every tile
 * goes stale at once, which would read as every printer failing. The front says so after
 * each snapshot while it lasts, so a lost socket forgets it.
 */
const brokerBanner = (() => {
  let since = null;
  const render = () => {
    $("broker-banner").hidden = since === null;
    document.body.classList.toggle("is-cut-off", since !== null);
    if (since !== null) setText($("broker-since"), t("broker.lost", { time: new Date(since * 1000).toLocaleTimeString(getLang()) }));
  };
  onLangChange(render);
  return {
    onFrame(frame) {
      since = frame.connected ? null : frame.since;
      render();
    },
    forget() {
      since = null;
      render();
    },
  };
})();

/** A refused WebSocket looks like a dead server: ask whether a login is what is missing. */
async function checkAccess() {
  if ((await loadSession()) && needsLogin() && (await login())) reconnectNow();
}

/** Show who is logged in, and what their role allows. */
function applySession() {
  const session = currentSession();
  $("who").hidden = session.access !== "tokens" || !session.role;
  setText($("who-name"), session.role ? `${session.name} · ${t(`session.role_${session.role}`)}` : "");
  $("add-printer").hidden = !can("admin");
  $("find-printers").hidden = !can("admin");
  $("audit-link").hidden = !can("admin");
}

/** Printers, Queue, History, Statistics, Audit log, Notifications, Cameras, Spools or one
 * printer's page, from the address (#queue, #printer/<id>...), so any can be bookmarked. */
function route() {
  const hash = location.hash;
  const printerId = printerOfHash(hash);
  const simple = { "#queue": "queue", [NOTIFY_HASH]: "notifications", [CAMERAS_HASH]: "cameras", [SPOOLS_HASH]: "spools", ...LEDGER_PAGES };
  const page = printerId !== null ? "printer" : simple[hash] || "fleet";
  document.body.dataset.page = page;
  showPrinterPage(printerId);
  showCamerasPage(page);
  showSpoolsPage(page);
  $("queue-view").hidden = page !== "queue";
  showLedgerPage(page);
  showNotificationsPage(page);
  $("fleet").hidden = page !== "fleet";
  /** @type {HTMLElement} */ (document.querySelector(".toolbar")).hidden = page !== "fleet";
  for (const link of /** @type {NodeListOf<HTMLElement>} */ (document.querySelectorAll("[data-page]"))) {
    if (link.dataset.page === page) link.setAttribute("aria-current", "page");
    else link.removeAttribute("aria-current");
  }
}

/** Event frames: console lines, queue changes, and the news an operator wants to hear about. */
function onEvent(frame) {
  const name = printers.get(frame.printer)?.name || frame.printer;
  if (frame.type === "queue") refreshQueue();
  else if (frame.type === "gcode_response") onConsoleFrame(frame);
  else if (frame.type === "broker") brokerBanner.onFrame(frame);
  else if (frame.type === "files") onFilesChanged(frame.printer);
  else if (frame.type === "connection" && frame.connection === "auth_failed") {
    toast({ kind: "error", title: name, message: `${t("notify.auth_failed")} ${frame.message || ""}`.trim() });
  } else if (frame.type === "klippy" && (frame.state === "shutdown" || frame.state === "error")) {
    toast({ kind: "warn", title: name, message: frame.message || t("notify.shutdown") });
    alertOperator({ kind: "error", title: name, message: frame.message || t("notify.shutdown") });
  } else if (frame.type === "config") {
    if (frame.ok) toast({ kind: "info", message: t("config.reloaded") });
    else toast({ kind: "error", title: t("config.refused"), message: frame.message });
  }
}

/**
 * Prints that finish or fail while the page is open: only a live step from printing or
 * paused, seen while the printer is connected. A printer that comes back (its job state
 * is empty while Klippy is away) or a snapshot shows its last job's end, long past: no toast.
 */
function onStoreChange(change) {
  lastData = Date.now();
  if (change.full) refreshQueue(0); // (re)connected: the queue may have moved meanwhile
  for (const { id, from, to } of change.transitions) {
    const p = printers.get(id);
    if (!p || p.connection !== "online" || (from !== "printing" && from !== "paused")) continue;
    if (to !== "complete" && to !== "error") continue;
    const filename = fmt.baseName(p.job?.filename);
    const kind = to === "complete" ? "ok" : "error";
    toast({ kind, title: p.name, message: t(`notify.${to}`, { filename }), timeout: to === "complete" ? 10000 : 0 });
    alertOperator({ kind, title: p.name, message: t(`notify.${to}`, { filename }) });
  }
}

async function main() {
  await loadLang(); // the page's language, before anything is labelled
  translateStatic(document);
  const lang = /** @type {HTMLSelectElement} */ ($("lang"));
  lang.value = getLang();
  lang.addEventListener("change", () =>
    setLang(lang.value).catch(() => {
      lang.value = getLang(); // its file did not load: the page stays as it was
      toast({ kind: "error", message: t("error.unknown") });
    }),
  );
  initTheme();
  initDensity($("density"));
  initAlerts($("alerts-notify"), $("alerts-sound"));
  initUtilisation($("utilisation"));
  initActions({ openDrawer, editPrinter: printerDialog, removePrinter });
  initOverview(
    {
      grid: $("grid"),
      table: $("table-wrap"),
      tbody: $("tbody"),
      empty: $("empty"),
      counts: $("counts"),
      shown: $("shown-count"),
      search: $("search"),
      state: $("filter-state"),
      tag: $("filter-tag"),
      location: $("filter-location"),
      sort: $("sort"),
      selectAll: $("select-all"),
      modeButtons: [...document.querySelectorAll("[data-mode]")],
    },
    {
      onAction: onCardButton,
      onSelection: updateBulkBar,
      onDropFiles: (id, files) => uploadDialog([id], files),
    },
  );
  for (const button of /** @type {NodeListOf<HTMLElement>} */ (document.querySelectorAll("[data-mode]"))) button.addEventListener("click", () => setMode(button.dataset.mode));
  initBulk($("bulk"), [...document.querySelectorAll("[data-select-group]")]);
  initDrawer({
    root: $("drawer"),
    title: $("drawer-title"),
    meta: $("drawer-meta"),
    status: $("drawer-status"),
    close: $("drawer-close"),
    tabs: [$("tab-files"), $("tab-console")],
    filesPanel: $("panel-files"),
    consolePanel: $("panel-console"),
    temps: $("drawer-temps"),
  });
  initQueue({
    list: $("queue-list"),
    empty: $("queue-empty"),
    summary: $("queue-summary"),
    count: $("queue-count"),
    pausedNote: $("queue-paused"),
    pause: $("queue-pause"),
    add: $("queue-add"),
    finished: $("queue-finished"),
  });
  window.addEventListener("hashchange", route);
  route();
  $("add-printer").addEventListener("click", () => printerDialog());
  $("find-printers").addEventListener("click", () => findPrinters());
  translateStatic(document); // the bulk bar and menus built above carry data-i18n too
  onLangChange(() => {
    lang.value = getLang();
    rebuild();
    updateBulkBar();
    relabelDrawer();
    relabelQueue();
    initDensity($("density"));
    initAlerts($("alerts-notify"), $("alerts-sound"));
    relabelUtilisation();
  });
  document.addEventListener("keydown", (event) => {
    const typing = /** @type {Element} */ (event.target).closest?.("input, textarea, select, [contenteditable]");
    if (event.key === "/" && !typing && !document.querySelector("dialog[open]")) {
      event.preventDefault();
      $("search").focus();
    }
  });
  subscribe(onStoreChange);
  onSessionChange(() => {
    applySession();
    rebuild();
    updateBulkBar();
    relabelQueue();
  });
  onLangChange(applySession);
  $("logout").addEventListener("click", async () => {
    await logout();
    location.reload(); // start over: the login dialog comes before any data
  });
  window.addEventListener("kybercore:unauthorized", async () => {
    if ((await loadSession()) && needsLogin()) await login();
  });
  await loadSession();
  applySession();
  if (needsLogin()) await login();
  showNow();
  startLive({ onEvent, onStatus: liveStatusHandler() });
}

main();
