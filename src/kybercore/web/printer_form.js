// Add, edit and remove printers. Validation is the backend's: the per-field problems of its
// 422 answer go under the fields they name, in the UI's language. The API key is write-only:
// never shown, never echoed.
import { ApiError, api } from "./api.js";
import { confirmDialog, modal, toast } from "./dialogs.js";
import { h } from "./dom.js";
import { fieldText, messageOf, t } from "./i18n.js";
import { facets, printers } from "./store.js";

const CAPS = ["nozzle_diameter", "material", "max_extruder_temp", "max_bed_temp"];
const AXES = ["x", "y", "z"];

function field(name, label, input, hint) {
  input.name = name;
  input.id = `pf-${name}`;
  const error = h("p", { class: "field-error", id: `pf-${name}-error`, hidden: true });
  const help = hint ? h("p", { class: "hint", id: `pf-${name}-hint`, text: hint }) : null;
  if (help) input.setAttribute("aria-describedby", help.id);
  return h("div", { class: "field", dataset: { field: name } }, h("label", { for: input.id, text: label }), input, help, error);
}

const text = (value = "", extra = {}) => h("input", { type: "text", value: value ?? "", autocomplete: "off", ...extra });
const num = (value, extra = {}) => h("input", { type: "number", value: typeof value === "number" ? String(value) : "", step: "any", min: "0", ...extra });

function buildForm(p) {
  const caps = p?.capabilities || {};
  const volume = caps.build_volume || {};
  const known = facets();
  const locations = h("datalist", { id: "pf-locations" }, known.locations.map((l) => h("option", { value: l })));
  const sites = h("datalist", { id: "pf-sites" }, known.sites.map((s) => h("option", { value: s })));
  const keyPlaceholder = p?.api_key_set ? t("form.api_key_keep") : t("form.optional");
  const parts = [
    field("name", t("form.name"), text(p?.name, { required: true, autofocus: true })),
    p ? null : field("id", t("form.id"), text("", { placeholder: t("form.id_placeholder"), pattern: "[a-z0-9][a-z0-9_-]{0,63}" }), t("form.id_hint")),
    field("moonraker_url", t("form.url"), text(p?.moonraker_url, { required: true, inputmode: "url", placeholder: "http://192.168.1.50:7125" })),
    field("api_key", t("form.api_key"), h("input", { type: "password", autocomplete: "new-password", placeholder: keyPlaceholder, value: "" }), t("form.api_key_hint")),
    p?.api_key_set ? h("label", { class: "check" }, h("input", { type: "checkbox", name: "clear_key" }), h("span", { text: t("form.api_key_clear") })) : null,
    field("model", t("form.model"), text(p?.model, { placeholder: "Voron 2.4" })),
    field("location", t("form.location"), text(p?.location, { list: "pf-locations" })),
    locations,
    field("site", t("form.site"), text(p?.site, { list: "pf-sites", pattern: "[a-z0-9][a-z0-9_-]{0,31}" }), t("form.site_hint")),
    sites,
    field("tags", t("form.tags"), text((p?.tags || []).join(", ")), t("form.tags_hint")),
    field("notes", t("form.notes"), h("textarea", { rows: 2, text: p?.notes || "" })),
    h("label", { class: "check" }, h("input", { type: "checkbox", name: "enabled", checked: p ? p.enabled : true }), h("span", { text: t("form.enabled") })),
    // Shown once the connection test failed: a printer that is off can still be added.
    p ? null : h("label", { class: "check save-anyway", hidden: true }, h("input", { type: "checkbox", name: "save_anyway" }), h("span", { text: t("form.save_anyway") })),
    h(
      "details",
      { class: "caps" },
      h("summary", { text: t("form.capabilities") }),
      h("p", { class: "hint", text: t("form.capabilities_hint") }),
      h(
        "div",
        { class: "caps-grid" },
        AXES.map((axis) => field(`capabilities.build_volume.${axis}`, t(`form.volume_${axis}`), num(volume[axis]))),
        field("capabilities.nozzle_diameter", t("form.nozzle"), num(caps.nozzle_diameter, { step: "0.05" })),
        field("capabilities.material", t("form.material"), text(caps.material, { placeholder: "PLA" })),
        field("capabilities.max_extruder_temp", t("form.max_hotend"), num(caps.max_extruder_temp)),
        field("capabilities.max_bed_temp", t("form.max_bed"), num(caps.max_bed_temp)),
      ),
    ),
  ];
  return h("div", { class: "form-grid printer-form" }, h("p", { class: "form-error", role: "alert", hidden: true }), parts);
}

/** The form's values as the API wants them (blank numbers left out). */
function read(form) {
  const value = (name) => form.elements[name]?.value.trim() ?? "";
  const number = (name) => (value(name) === "" ? null : Number(value(name)));
  const caps = {};
  for (const name of CAPS) caps[name] = name === "material" ? value(`capabilities.${name}`) || null : number(`capabilities.${name}`);
  const axes = Object.fromEntries(AXES.map((a) => [a, number(`capabilities.build_volume.${a}`)]));
  caps.build_volume = AXES.every((a) => axes[a] === null) ? null : Object.fromEntries(AXES.filter((a) => axes[a] !== null).map((a) => [a, axes[a]]));
  return {
    name: value("name"),
    id: value("id"),
    moonraker_url: value("moonraker_url"),
    api_key: form.elements.api_key.value,
    clear_key: Boolean(form.elements.clear_key?.checked),
    model: value("model"),
    location: value("location"),
    site: value("site"),
    tags: value("tags").split(",").map((s) => s.trim()).filter(Boolean),
    notes: form.elements.notes.value,
    enabled: form.elements.enabled.checked,
    capabilities: caps,
  };
}

function createBody(v) {
  const body = { name: v.name, moonraker_url: v.moonraker_url, model: v.model, location: v.location, site: v.site, tags: v.tags, notes: v.notes, enabled: v.enabled };
  if (v.id) body.id = v.id;
  if (v.api_key) body.api_key = v.api_key;
  const caps = Object.fromEntries(Object.entries(v.capabilities).filter(([, x]) => x !== null));
  if (Object.keys(caps).length) body.capabilities = caps;
  return body;
}

/** Only what changed (PATCH keeps the rest); a cleared capability is sent as null. */
function patchBody(p, v) {
  const body = {};
  for (const key of ["name", "moonraker_url", "model", "location", "site", "notes", "enabled"]) if (v[key] !== (p[key] ?? "")) body[key] = v[key];
  if (JSON.stringify(v.tags) !== JSON.stringify(p.tags || [])) body.tags = v.tags;
  if (v.api_key) body.api_key = v.api_key;
  else if (v.clear_key) body.api_key = "";
  const caps = {};
  const old = p.capabilities || {};
  for (const name of CAPS) if ((v.capabilities[name] ?? null) !== (old[name] ?? null)) caps[name] = v.capabilities[name];
  if (JSON.stringify(v.capabilities.build_volume) !== JSON.stringify(old.build_volume ?? null)) caps.build_volume = v.capabilities.build_volume;
  if (Object.keys(caps).length) body.capabilities = caps;
  return body;
}

/** The form's box for a field path: "tags.1" is the tags field, "capabilities.x.y" the
 * nearest named box ("capabilities.build_volume" has none of its own: its axes have). */
function boxFor(form, path) {
  const parts = path.split(".").filter((part) => !/^\d+$/.test(part));
  while (parts.length) {
    const box = form.querySelector(`[data-field="${CSS.escape(parts.join("."))}"]`);
    if (box) return box;
    parts.pop();
  }
  return null;
}

/** Take the error messages of showErrors away. */
export function clearErrors(form) {
  for (const el of form.querySelectorAll(".field-error")) {
    el.hidden = true;
    el.textContent = "";
  }
  for (const el of form.querySelectorAll("[aria-invalid]")) el.removeAttribute("aria-invalid");
  const top = form.querySelector(".form-error");
  if (top) top.hidden = true;
}

/** Put the backend's per-field problems (422 `fields`) under the fields they name (boxes
 * marked data-field, with a .field-error), the rest, and any other error, in the form's
 * .form-error. Shared with the notification forms. */
export function showErrors(form, error) {
  clearErrors(form);
  const general = [];
  let first = null;
  for (const problem of error.fields || []) {
    const message = fieldText(problem);
    const box = boxFor(form, problem.field || "");
    if (!box) {
      general.push(`${problem.field}: ${message}`);
      continue;
    }
    const input = box.querySelector("input, textarea, select");
    const note = box.querySelector(".field-error");
    note.textContent = note.textContent ? `${note.textContent} ${message}` : message;
    note.hidden = false;
    input.setAttribute("aria-invalid", "true");
    const described = (input.getAttribute("aria-describedby") || "").split(" ").filter((x) => x && x !== note.id);
    input.setAttribute("aria-describedby", [note.id, ...described].join(" "));
    if (box.closest("details.caps")) form.querySelector("details.caps").open = true;
    first = first || input;
  }
  if (!error.fields?.length) general.push(messageOf(error));
  const top = form.querySelector(".form-error");
  top.textContent = general.join(" ");
  top.hidden = general.length === 0;
  (first || top).focus?.();
}

const UNREACHABLE = new Set(["printer_unreachable", "printer_timeout", "printer_auth_failed"]);

/** The connection test failed: say why, and offer to save the printer anyway. */
function offerSaveAnyway(form, error) {
  showErrors(form, { message: t("form.unreachable", { detail: error.message }) });
  const box = form.querySelector(".save-anyway");
  box.hidden = false;
  box.querySelector("input").focus();
}

/** Add a printer (p undefined) or edit one; resolves when the dialog closes. */
export async function printerDialog(id) {
  const p = id ? printers.get(id) : undefined;
  if (id && !p) return;
  const buttons = [
    { label: t("action.back"), cancel: true },
    { label: p ? t("form.save") : t("form.add"), value: "save", kind: "primary" },
  ];
  if (p) buttons.unshift({ label: t("action.remove"), value: "remove", kind: "danger ghost" });
  const value = await modal({
    title: p ? t("form.edit_title", { name: p.name }) : t("form.add_title"),
    body: buildForm(p),
    wide: true,
    buttons,
    onSubmit: async (choice, form) => {
      if (choice === "remove") return "remove";
      const values = read(form);
      try {
        if (p) {
          const body = patchBody(p, values);
          if (Object.keys(body).length) await api.updatePrinter(p.id, body);
          toast({ kind: "ok", title: values.name || p.name, message: t("form.saved") });
        } else {
          const saveAnyway = /** @type {HTMLInputElement | null} */ (form.elements.namedItem("save_anyway"));
          const anyway = Boolean(saveAnyway?.checked);
          const created = await api.addPrinter(createBody(values), { check: !anyway });
          const message = t(anyway ? "form.added_unchecked" : "form.added", { id: created.id });
          toast({ kind: anyway ? "warn" : "ok", title: created.name, message });
        }
        return "saved";
      } catch (error) {
        if (!p && error instanceof ApiError && UNREACHABLE.has(error.code)) offerSaveAnyway(form, error);
        else showErrors(form, error);
        return false;
      }
    },
  });
  if (value === "remove") await removePrinter(id);
}

export async function removePrinter(id) {
  const p = printers.get(id);
  if (!p) return;
  const ok = await confirmDialog({
    title: t("form.remove_title", { name: p.name }),
    message: t("form.remove_body"),
    confirmLabel: t("action.remove"),
    danger: true,
  });
  if (!ok) return;
  try {
    await api.removePrinter(id);
    toast({ kind: "ok", title: p.name, message: t("form.removed") });
  } catch (error) {
    toast({ kind: "error", title: p.name, message: messageOf(error) });
  }
}
