// Noise control on the Notifications page: cooldown, storm folding, grace periods (GET/PUT
// /api/notifications/settings). The API speaks seconds; a farm operator thinks in minutes
// (seconds for the short fold window). Everyone may read them, only an admin change them.
import { api } from "./api.js";
import { h, setText } from "./dom.js";
import { messageOf, t } from "./i18n.js";
import { clearErrors, showErrors } from "./printer_form.js";
import { can } from "./session.js";

/** @type {[field: string, label: string, unit: string, scale: number][]} [API field, label key, unit key, seconds per unit] */
const FIELDS = [
  ["cooldown_s", "nt.set.cooldown", "nt.unit.minutes", 60],
  ["fold_window_s", "nt.set.fold_window", "nt.unit.seconds", 1],
  ["storm_threshold", "nt.set.storm_threshold", "nt.unit.printers", 1],
  ["offline_grace_s", "nt.set.offline_grace", "nt.unit.minutes", 60],
  ["plate_wait_s", "nt.set.plate_wait", "nt.unit.minutes", 60],
  ["job_blocked_s", "nt.set.job_blocked", "nt.unit.minutes", 60],
  ["unreported_grace_s", "nt.set.unreported_grace", "nt.unit.seconds", 1],
];

let els = null;
let current = null; // the settings as the API last answered them

/** The FIELDS entry of an API field. */
function fieldOf(name) {
  const entry = FIELDS.find(([field]) => field === name);
  if (!entry) throw new Error(`no setting ${name}`);
  return entry;
}

/** Build the noise-control form into `root` (a section). */
export function initSettings(root) {
  const rows = FIELDS.map(([name, , unitKey]) => {
    const whole = unitKey === "nt.unit.printers";
    const input = h("input", { type: "number", name, id: `nts-${name}`, min: "0", step: whole ? "1" : "any", inputmode: whole ? "numeric" : "decimal" });
    const label = h("label", { for: input.id });
    const unit = h("span", { class: "nt-unit", id: `nts-${name}-unit` });
    input.setAttribute("aria-describedby", unit.id);
    const error = h("p", { class: "field-error", id: `nts-${name}-error`, hidden: true });
    return { name, label, unit, input, box: h("div", { class: "field nt-setting", dataset: { field: name } }, label, h("div", { class: "nt-with-unit" }, input, unit), error) };
  });
  els = {
    title: h("h3", { id: "nt-settings-title" }),
    hint: h("p", { class: "hint" }),
    readonly: h("p", { class: "hint nt-readonly", hidden: true }),
    form: h("form", { class: "nt-settings", novalidate: true }),
    legend: h("legend", { class: "visually-hidden" }),
    save: h("button", { type: "submit", class: "btn primary" }),
    status: h("p", { class: "nt-status", role: "status" }),
    rows,
  };
  els.form.append(
    h("p", { class: "form-error", role: "alert", hidden: true }),
    h("fieldset", { class: "nt-settings-grid" }, els.legend, rows.map((r) => r.box)),
    h("div", { class: "nt-settings-actions" }, els.save, els.status),
  );
  els.form.addEventListener("submit", save);
  root.setAttribute("aria-labelledby", els.title.id);
  root.append(els.title, els.hint, els.readonly, els.form);
  relabelSettings();
}

/** Labels in the current language; inputs read-only unless the user is an admin. */
export function relabelSettings() {
  if (!els) return;
  setText(els.title, t("nt.settings"));
  setText(els.legend, t("nt.settings"));
  setText(els.hint, t("nt.settings_hint"));
  setText(els.readonly, t("nt.settings_readonly"));
  setText(els.save, t("nt.settings_save"));
  for (const row of els.rows) {
    const [, label, unit] = fieldOf(row.name);
    setText(row.label, t(label));
    setText(row.unit, t(unit));
  }
  const admin = can("admin");
  els.readonly.hidden = admin;
  els.save.hidden = !admin;
  for (const row of els.rows) row.input.readOnly = !admin;
}

/** Fetch the settings and show them. */
export async function loadSettings() {
  try {
    current = await api.notifySettings();
  } catch (error) {
    setText(els.status, messageOf(error));
    return;
  }
  for (const row of els.rows) row.input.value = String(toUnit(row.name, current[row.name]));
}

function toUnit(name, value) {
  const scale = fieldOf(name)[3];
  return Math.round((value / scale) * 100) / 100;
}

function fromUnit(name, text) {
  const scale = fieldOf(name)[3];
  const value = text.trim() === "" ? NaN : Number(text);
  // Left for the backend to refuse with its own message, field by field.
  if (!Number.isFinite(value)) return text;
  return value * scale;
}

async function save(event) {
  event.preventDefault();
  if (!can("admin")) return;
  const body = { ...current };
  for (const row of els.rows) body[row.name] = fromUnit(row.name, row.input.value);
  els.save.disabled = true;
  setText(els.status, "");
  try {
    current = (await api.saveNotifySettings(body)) || body;
    clearErrors(els.form);
    setText(els.status, t("nt.settings_saved"));
    for (const row of els.rows) row.input.value = String(toUnit(row.name, current[row.name]));
  } catch (error) {
    showErrors(els.form, error);
  } finally {
    els.save.disabled = false;
  }
}
