// The printer drawer: a side panel (non-modal, the fleet stays visible and live) with the
// printer's temperature graph, and its files and console as tabs.
import { consoleResponse, hideConsole, showConsole } from "./console.js";
import { setText } from "./dom.js";
import { hideFiles, refreshFileButtons, showFiles } from "./files.js";
import { t } from "./i18n.js";
import { printers, statusOf, subscribe } from "./store.js";
import { hideTemperatures, relabelTemperatures, showTemperatures } from "./temps.js";
import { show } from "./watch.js";

let els = null;
let openId = null;
let tab = "files";
let opener = null;

export function initDrawer(elements) {
  els = elements;
  els.close.addEventListener("click", closeDrawer);
  els.root.addEventListener("keydown", (event) => {
    if (event.key === "Escape" && !event.defaultPrevented) {
      event.preventDefault();
      closeDrawer();
    }
  });
  for (const button of els.tabs) {
    button.addEventListener("click", () => selectTab(button.dataset.tab, true));
    button.addEventListener("keydown", (event) => {
      if (event.key !== "ArrowLeft" && event.key !== "ArrowRight") return;
      event.preventDefault();
      const next = els.tabs.find((b) => b !== button);
      selectTab(next.dataset.tab, true);
      next.focus();
    });
  }
  subscribe((change) => {
    if (!openId) return;
    if (change.removed.has(openId) || !printers.has(openId)) return closeDrawer();
    if (change.changed.has(openId)) {
      updateHeader();
      refreshFileButtons();
    }
  });
}

/** Open the drawer on printer `id`, on the "files" or "console" tab. */
export function openDrawer(id, which = "files") {
  if (!printers.has(id)) return;
  if (!openId) opener = document.activeElement;
  if (openId !== id && els.temps) showTemperatures(els.temps, id);
  openId = id;
  show("drawer", [id]); // its graph and heaters need the full view, wherever its tile is
  els.root.hidden = false;
  document.body.classList.add("drawer-open");
  updateHeader();
  selectTab(which, true);
}

export function closeDrawer() {
  if (!openId) return;
  openId = null;
  show("drawer", []);
  hideFiles();
  hideConsole();
  hideTemperatures();
  els.root.hidden = true;
  document.body.classList.remove("drawer-open");
  if (opener && opener.isConnected) opener.focus();
  opener = null;
}

/** Re-render for a language change. */
export function relabelDrawer() {
  if (openId) {
    updateHeader();
    selectTab(tab, false);
    relabelTemperatures();
  }
}

export function onConsoleFrame(frame) {
  consoleResponse(frame);
}

function updateHeader() {
  const p = printers.get(openId);
  if (!p) return;
  setText(els.title, p.name);
  setText(els.meta, [p.id, p.model, p.location].filter(Boolean).join(" · "));
  const status = statusOf(p);
  els.status.dataset.status = status.group;
  setText(els.status, t(status.key));
}

function selectTab(which, focusContent) {
  tab = which === "console" ? "console" : "files";
  for (const button of els.tabs) {
    const on = button.dataset.tab === tab;
    button.setAttribute("aria-selected", String(on));
    button.tabIndex = on ? 0 : -1;
  }
  els.filesPanel.hidden = tab !== "files";
  els.consolePanel.hidden = tab !== "console";
  let target;
  if (tab === "files") {
    hideConsole();
    target = showFiles(els.filesPanel, openId);
    els.consolePanel.replaceChildren();
  } else {
    hideFiles();
    target = showConsole(els.consolePanel, openId);
    els.filesPanel.replaceChildren();
  }
  if (focusContent && target) target.focus();
}
