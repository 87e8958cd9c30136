// One printer's page (#printer/<id>), laid out as Mainsail and Fluidd users know it: the
// temperatures with their graph, the toolhead, extruder, fan and factors, the macros, the
// console, the files and the webcam. Linkable; the browser's back button returns to the
// fleet. Everything it does goes through the same validated routes as the dashboard.
import { send } from "./actions.js";
import { api } from "./api.js";
import { showConsole, hideConsole } from "./console.js";
import { h, icon, setHidden, setText } from "./dom.js";
import { closeDrawer } from "./drawer.js";
import { hideFiles, showFiles } from "./files.js";
import * as fmt from "./format.js";
import { onLangChange, t } from "./i18n.js";
import { buildControls, card, updateControls } from "./printer_controls.js";
import { JobCard } from "./printer_job.js";
import { ObjectsCard } from "./printer_objects.js";
import { onQueueChange } from "./queue_data.js";
import { can } from "./session.js";
import { printers, serverNow, statusOf, subscribe } from "./store.js";
import { hideTemperatures, showTemperatures } from "./temps.js";
import { show } from "./watch.js";
import { renderWebcam, stopWebcam } from "./webcam_view.js";

const PREFIX = "#printer/";
const HEATERS = [
  ["extruder", "extruder", "temps.extruder"],
  ["bed", "bed", "temps.bed"],
];

let root = null;
let shownId = null; // the printer on screen, null when the page is hidden
let els = null;
let seen = false; // the fleet's first snapshot has arrived: a printer not in it is unknown

/** The printer id in an address like #printer/<id>, else null. */
export function printerOfHash(hash) {
  return hash.startsWith(PREFIX) ? decodeURIComponent(hash.slice(PREFIX.length)) : null;
}

/** Show the page for printer `id` (null: hide it). */
export function showPrinterPage(id) {
  root ||= init(document.getElementById("printer-view"));
  if (id === shownId && id !== null) return;
  leave();
  shownId = id;
  show("page", id === null ? [] : [id]);
  root.hidden = id === null;
  if (id === null) return;
  closeDrawer(); // the console, files and graph are the page's now
  build(id);
  document.title = `${printers.get(id)?.name || id} · KyberCore`;
}

function init(el) {
  subscribe((change) => {
    if (change.full) seen = true;
    if (!shownId) return;
    const present = printers.has(shownId);
    // First data after a reload, a printer that appears or goes: build again.
    if (!els ? present || change.full : !present) return build(shownId);
    if (change.changed.has(shownId)) update();
  });
  onLangChange(() => {
    if (shownId) build(shownId);
  });
  // A plate cleared or held elsewhere (a tile, another browser) shows here too.
  onQueueChange((change) => {
    if (els && change.gates.has(els.id)) update();
  });
  // A printer gone quiet (or paused) sends nothing: the age of its data grows without a
  // frame, and the print's objects are read again all the same.
  setInterval(() => {
    const p = els && printers.get(els.id);
    if (!p) return;
    els.job.updateStale(p, serverNow());
    els.objects.update(p);
  }, 1000);
  return el;
}

function leave() {
  if (!shownId) return;
  release();
  els = null;
  document.title = "KyberCore";
}

/** Hand back the shared panels (graph, console, files, webcam) the page had taken. */
function release() {
  stopWebcam();
  hideTemperatures();
  hideConsole();
  hideFiles();
}

function build(id) {
  release();
  const p = printers.get(id);
  const back = h("a", { href: "#", class: "btn ghost pp-back" }, h("span", { "aria-hidden": "true", text: "← " }), t("pp.back"));
  if (!p) {
    els = null;
    const why = seen ? h("p", { role: "alert", text: t("pp.not_found", { id }) }) : h("p", { class: "muted", text: t("pp.loading") });
    root.replaceChildren(h("div", { class: "pp-missing" }, back, why));
    return;
  }
  const title = h("h1", { class: "pp-title", id: "pp-title" });
  const pill = h("span", { class: "pill" });
  const meta = h("p", { class: "meta" });
  const webUi = h("a", { class: "btn small ghost pp-webui", target: "_blank", rel: "noopener", hidden: true });
  const restart = h("button", { type: "button", class: "btn small primary pp-restart", hidden: true, onclick: () => act(id, "firmware_restart") }, icon("refresh"), h("span", { text: t("pp.firmware_restart") }));
  const estop = h(
    "button",
    { type: "button", class: "btn estop pp-estop", "aria-label": t("aria.estop", { short: t("action.estop_short"), action: t("action.emergency_stop") }), onclick: () => act(id, "emergency_stop") },
    icon("bolt"),
    h("span", { class: "estop-label", text: t("action.estop_short") }),
  );
  const message = h("p", { class: "pp-message", role: "status" });
  const graph = h("div", { class: "pp-graph" });
  const heaters = h("tbody");
  const consolePanel = h("div", { class: "pp-console" });
  const filesPanel = h("div", { class: "pp-files" });
  const webcam = card("printer-webcam", t("pp.webcam"));
  webcam.classList.add("pp-webcam");
  webcam.hidden = true; // shown by renderWebcam when the printer has a webcam
  const controls = buildControls(id);
  const job = new JobCard(id, card);
  const objects = new ObjectsCard(id, card);
  els = { id, title, pill, meta, webUi, restart, estop, message, heaters, rows: {}, controls, webcam, job, objects };
  for (const [view, , label] of HEATERS) heaters.append(heaterRow(id, view, label));
  root.replaceChildren(
    h("header", { class: "pp-head" }, back, h("div", { class: "pp-title-box" }, title, meta), pill, h("span", { class: "pp-head-actions" }, webUi, restart, estop)),
    message,
    h(
      "div",
      { class: "pp-grid" },
      job.el,
      objects.el,
      card("pp-temps", t("pp.temps"), graph, h("table", { class: "pp-heaters" }, h("thead", {}, h("tr", {}, ...["pp.heater", "pp.current", "pp.target", "pp.power"].map((k) => h("th", { scope: "col", text: t(k) })), h("th", { scope: "col", text: t("pp.set") }))), heaters)),
      ...controls.cards,
      webcam,
      card("pp-console-card", t("pp.console"), consolePanel),
      card("pp-files-card", t("pp.files"), filesPanel),
    ),
  );
  update();
  showTemperatures(graph, id);
  showConsole(consolePanel, id);
  showFiles(filesPanel, id, { wide: true });
  renderWebcam(webcam, id);
  findWebUi(id, webUi);
  title.tabIndex = -1;
  title.focus();
}

/** One heater: now, target, power, and a field to set a new target. */
function heaterRow(id, view, label) {
  const input = h("input", { type: "number", min: "0", max: "400", step: "1", inputmode: "numeric", class: "pp-target-input", "aria-label": t("pp.set_target_named", { heater: t(label) }) });
  const form = h(
    "form",
    {
      class: "pp-target-form",
      onsubmit: (event) => {
        event.preventDefault();
        if (input.value === "") return;
        act(id, "set_temperature", { [view]: Number(input.value) }).then((ok) => {
          if (ok) input.value = "";
        });
      },
    },
    input,
    h("button", { type: "submit", class: "btn small", text: t("pp.set") }),
  );
  const cells = { now: h("td", { class: "pp-now" }), target: h("td", { class: "pp-target" }), power: h("td", { class: "pp-power" }), form };
  els.rows[view] = cells;
  return h("tr", { dataset: { heater: view } }, h("th", { scope: "row", text: t(label) }), cells.now, cells.target, cells.power, h("td", {}, form));
}

/** Refresh what the live view changes. */
function update() {
  const p = printers.get(els.id);
  if (!p) return;
  const status = statusOf(p);
  const online = p.connection === "online";
  setText(els.title, p.name);
  setText(els.meta, [p.id, p.model, p.location].filter(Boolean).join(" · "));
  els.pill.dataset.status = status.group;
  setText(els.pill, t(status.key));
  root.dataset.status = status.group;
  const operator = can("operator");
  const actions = p.actions || {};
  // Klippy shut down (an e-stop, a heater fault): the one button that brings it back.
  setHidden(els.restart, !(online && (p.klippy_state === "shutdown" || p.klippy_state === "error")));
  els.restart.disabled = !operator || !actions.firmware_restart;
  els.estop.disabled = !operator || !actions.emergency_stop;
  setText(els.message, online ? p.klippy_message || "" : p.connection_error || t(status.key));
  for (const [view] of HEATERS) {
    const heater = p[view] || {};
    const cells = els.rows[view];
    setText(cells.now, online ? fmt.temp(heater.temperature) : "—");
    setText(cells.target, online ? fmt.target(heater.target) : "—");
    setText(cells.power, online && typeof heater.power === "number" ? `${Math.round(heater.power * 100)} %` : "—");
    for (const field of cells.form.elements) field.disabled = !operator || !actions.set_temperature;
  }
  updateControls(els.controls, p);
  els.job.update(p);
  els.objects.update(p);
}

/** Run an action; the e-stop and the firmware restart here are one click (nothing to lose:
 * the printer is already stopped, or must stop now). Returns whether it succeeded. */
async function act(id, action, params = {}) {
  try {
    await send(id, action, params);
    return true;
  } catch {
    return false; // send() showed what went wrong
  }
}

async function findWebUi(id, link) {
  try {
    const found = await api.webUi(id);
    if (!found.kind || shownId !== id) return;
    const ui = found.kind === "mainsail" ? "Mainsail" : "Fluidd";
    link.href = found.url;
    link.textContent = t("pp.open_in", { ui });
    link.hidden = false;
  } catch {
    // No link is the honest answer when the probe itself fails (the printer went away).
  }
}
