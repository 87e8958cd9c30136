// Per-printer actions: confirmation for the drastic ones, the real result or the backend's
// error, and "confirmation_required" warnings shown to the user before sending again.
import { ApiError, api } from "./api.js";
import { confirmDialog, modal, openMenu, toast } from "./dialogs.js";
import { h } from "./dom.js";
import { GATE_ACTIONS, gateAction } from "./gates.js";
import { messageOf, reasonText, t } from "./i18n.js";
import { gateState } from "./queue_data.js";
import { can } from "./session.js";
import { printers } from "./store.js";

/**
 * Actions that ask first; all of them are drastic. Not the emergency stop of one printer:
 * it must be one click (its undo is a firmware restart); the bulk bar asks for many.
 */
export const CONFIRM = new Set(["cancel", "firmware_restart", "restart"]);

/** @type {{openDrawer: (id: string, tab?: string) => any, editPrinter: (id: string) => any, removePrinter: (id: string) => any}} */
let panels = { openDrawer: () => {}, editPrinter: () => {}, removePrinter: () => {} };

export function initActions(handlers) {
  panels = { ...panels, ...handlers };
}

const nameOf = (id) => printers.get(id)?.name || id;

/** What a button or menu item on a card asked for. */
export async function onCardAction(id, action, opener) {
  if (action === "files" || action === "console") return panels.openDrawer(id, action);
  if (action === "more") return moreMenu(id, opener);
  if (GATE_ACTIONS.has(action)) return gateAction(id, action);
  return runAction(id, action);
}

/** A card's button pressed: its action, with the button marked busy until it is answered. */
export async function onCardButton(id, action, button) {
  button.classList.add("busy");
  try {
    await onCardAction(id, action, button);
  } finally {
    button.classList.remove("busy");
  }
}

function moreMenu(id, anchor) {
  const p = printers.get(id);
  const allowed = (action) => can("operator") && Boolean(p?.actions?.[action]);
  const item = (action, iconName, extra = {}) => ({
    label: t(`action.${action}`),
    icon: iconName,
    disabled: !allowed(action),
    onSelect: () => runAction(id, action),
    ...extra,
  });
  openMenu(
    anchor,
    [
      item("start", "start", { label: t("action.start_file"), onSelect: () => panels.openDrawer(id, "files") }),
      item("home", "home"),
      item("set_temperature", "temp", { label: t("action.set_temperature_dots") }),
      item("firmware_restart", "restart", { danger: true }),
      item("restart", "restart", { danger: true }),
      { separator: true },
      gateState(id) === "available"
        ? { label: t("gate.hold"), icon: "pause", disabled: !can("operator"), onSelect: () => gateAction(id, "hold") }
        : { label: t("gate.release"), icon: "resume", disabled: !can("operator") || gateState(id) === "awaiting_clear", onSelect: () => gateAction(id, "release") },
      { separator: true },
      { label: t("action.edit"), icon: "edit", disabled: !can("admin"), onSelect: () => panels.editPrinter(id) },
      { label: t("action.remove"), icon: "remove", danger: true, disabled: !can("admin"), onSelect: () => panels.removePrinter(id) },
    ],
    t("aria.more", { name: nameOf(id) }),
  );
}

/**
 * Ask for what the action needs, confirm if drastic, send it, report the outcome.
 * @param {string} id
 * @param {string} action
 * @param {Record<string, unknown>} [params]
 */
export async function runAction(id, action, params = {}) {
  const name = nameOf(id);
  if (action === "set_temperature") {
    const targets = await temperatureDialog([id]);
    if (!targets) return null;
    params = targets;
  }
  if (CONFIRM.has(action)) {
    const ok = await confirmDialog({
      title: t(`confirm.${action}.title`, { name }),
      message: t(`confirm.${action}.body`),
      confirmLabel: t(`action.${action}`),
      danger: true,
    });
    if (!ok) return null;
  }
  return send(id, action, params).catch(() => null); // failures were shown by send()
}

/** Start a file: dry run first, so warnings are shown (in the UI's language) before it runs. */
export async function startPrint(id, filename) {
  let verdict;
  try {
    verdict = await api.check(id, "start", { filename });
  } catch (error) {
    failed(id, "start", error);
    return null;
  }
  if (verdict.level === "block") {
    failed(id, "start", { reasons: verdict.reasons, message: t("error.blocked") });
    return null;
  }
  let confirm = false;
  if (verdict.level === "warn") {
    confirm = await confirmWarnings(id, verdict.reasons);
    if (!confirm) return null;
  }
  return send(id, "start", { filename }, confirm).catch(() => null);
}

/**
 * Send an action; on "confirmation_required", show the warnings and offer to go ahead.
 * The outcome is shown as a toast (unless report is false); failures are also thrown.
 */
export async function send(id, action, params = {}, confirm = false, report = true) {
  try {
    const result = action === "gcode" ? await api.gcode(id, params.script, { confirm }) : await api.act(id, action, { ...params, confirm });
    if (report) succeeded(id, action, params, result);
    return result;
  } catch (error) {
    if (error instanceof ApiError && error.code === "confirmation_required" && !confirm) {
      if (await confirmWarnings(id, warningsOf(error))) return send(id, action, params, true, report);
      return null;
    }
    if (report) failed(id, action, error);
    throw error;
  }
}

/**
 * The warnings behind a confirmation_required answer: the 409 carries them in
 * error.reasons ({code, level: "warn", en, es}); without any, its message.
 */
export function warningsOf(error) {
  const warnings = (error.reasons || []).filter((r) => r.level === "warn");
  if (warnings.length) return warnings;
  return [{ level: "warn", en: error.message, es: error.message }];
}

export function confirmWarnings(id, reasons) {
  return confirmDialog({
    title: t("confirm.warnings.title", { name: nameOf(id) }),
    message: t("confirm.warnings.body"),
    details: reasons.filter((r) => r.level !== "ok").map((r) => ({ level: r.level, text: reasonText(r) })),
    confirmLabel: t("action.go_ahead"),
  });
}

export function doneText(action, params = {}) {
  return t(`done.${action}`, { filename: params.filename || "" });
}

function succeeded(id, action, params, result) {
  const warned = (result?.reasons || []).filter((r) => r.level === "warn").map(reasonText);
  toast({ kind: "ok", title: nameOf(id), message: [doneText(action, params), ...warned].join(" ") });
}

export function failed(id, action, error) {
  toast({ kind: "error", title: `${nameOf(id)} · ${t(`action.${action}`)}`, message: messageOf(error) });
}

// -- temperatures ----------------------------------------------------------------------------

const PRESETS = [
  { key: "preset.pla", extruder: 205, bed: 60 },
  { key: "preset.petg", extruder: 240, bed: 80 },
  { key: "preset.abs", extruder: 250, bed: 100 },
  { key: "preset.off", extruder: 0, bed: 0 },
];

/** Ask for hotend/bed targets; sends the action itself for one printer, returns params. */
export async function temperatureDialog(ids, { sendIt = true } = {}) {
  const first = printers.get(ids[0]);
  const caps = first?.capabilities || {};
  const field = (name, label, max, value) =>
    h(
      "label",
      { class: "field" },
      h("span", { text: label }),
      h("input", { type: "number", name, min: "0", max: max ?? "", step: "1", inputmode: "numeric", value: typeof value === "number" && value > 0 ? String(value) : "", placeholder: t("temp.keep") }),
    );
  const error = h("p", { class: "form-error", role: "alert", hidden: true });
  const extruder = field("extruder", t("temp.hotend_target"), caps.max_extruder_temp, first?.extruder?.target);
  const bed = field("bed", t("temp.bed_target"), caps.max_bed_temp, first?.bed?.target);
  const presets = h(
    "div",
    { class: "presets", role: "group", "aria-label": t("temp.presets") },
    PRESETS.map((preset) =>
      h("button", {
        type: "button",
        class: "btn small",
        text: `${t(preset.key)} ${preset.extruder ? `${preset.extruder}/${preset.bed}°` : ""}`.trim(),
        onclick: () => {
          /** @type {HTMLInputElement} */ (extruder.querySelector("input")).value = String(preset.extruder);
          /** @type {HTMLInputElement} */ (bed.querySelector("input")).value = String(preset.bed);
        },
      }),
    ),
  );
  /** @type {{extruder: number | undefined, bed: number | undefined} | null} */
  let params = null;
  const value = await modal({
    title: ids.length === 1 ? t("temp.title_one", { name: nameOf(ids[0]) }) : t("temp.title_many", { n: ids.length }),
    body: h("div", { class: "form-grid" }, presets, extruder, bed, error),
    buttons: [
      { label: t("action.back"), cancel: true },
      { label: t("temp.apply"), value: "apply", kind: "primary" },
    ],
    onSubmit: async (_value, form) => {
      /** @param {string} name */
      const read = (name) => {
        const raw = /** @type {HTMLInputElement} */ (form.elements.namedItem(name)).value.trim();
        return raw === "" ? undefined : Number(raw);
      };
      params = { extruder: read("extruder"), bed: read("bed") };
      if (params.extruder === undefined && params.bed === undefined) {
        error.textContent = t("temp.need_one");
        error.hidden = false;
        return false;
      }
      if (!sendIt || ids.length !== 1) return "apply";
      try {
        await send(ids[0], "set_temperature", params, false, false);
        return "sent";
      } catch (err) {
        error.textContent = messageOf(err);
        error.hidden = false;
        return false;
      }
    },
  });
  if (value === "apply") return params;
  return null;
}
