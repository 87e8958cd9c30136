// "Add job": a G-code file, its copies and what a printer needs to run it (material,
// nozzle, a printer, more under "More options"), uploaded with a progress bar. A job no
// printer could ever print is refused by the backend with the reason per printer, shown
// here in the UI's language.
import { ApiError, uploadJob } from "./api.js";
import { modal, toast } from "./dialogs.js";
import { h } from "./dom.js";
import * as fmt from "./format.js";
import { messageOf, reasonText, t } from "./i18n.js";
import { refreshQueue } from "./queue_data.js";
import { printers } from "./store.js";
import { dropZone } from "./uploads.js";

function field(label, input, hint) {
  return h("label", { class: "field", dataset: { field: input.name } }, h("span", { text: label }), input, hint ? h("small", { class: "hint", text: hint }) : null);
}

function options(values) {
  return [...new Set(values.filter(Boolean))].sort((a, b) => a.localeCompare(b)).map((value) => h("option", { value }));
}

/** The fleet's materials and models, offered as suggestions. */
function suggestions() {
  const fleet = [...printers.values()];
  return {
    materials: h("datalist", { id: "job-materials" }, options(fleet.map((p) => p.capabilities?.material))),
    models: h("datalist", { id: "job-models" }, options(fleet.map((p) => p.model))),
  };
}

/** Open the dialog; resolves once it is closed. */
export async function jobDialog() {
  let file = null;
  /** @type {import("./api.js").Upload | null} */
  let sending = null;
  const chosen = h("p", { class: "chosen-file", text: t("upload.none_chosen") });
  const { zone } = dropZone((files) => {
    file = files[0];
    chosen.textContent = `${file.name} · ${fmt.size(file.size)}`;
  });
  const input = (name, attrs = {}) => h("input", { name, autocomplete: "off", ...attrs });
  const { materials, models } = suggestions();
  const printer = h(
    "select",
    { name: "printer" },
    h("option", { value: "", text: t("jobform.printer_any") }),
    [...printers.values()].sort((a, b) => a.name.localeCompare(b.name)).map((p) => h("option", { value: p.id, text: p.name })),
  );
  const mismatch = h("input", { type: "checkbox", name: "allow_mismatch" });
  const bar = h("span", { class: "bar" });
  const progress = h("div", { class: "progress", role: "progressbar", "aria-label": t("upload.progress"), "aria-valuemin": "0", "aria-valuemax": "100", "aria-valuenow": "0", hidden: true }, bar);
  const error = h("div", { class: "form-error", role: "alert", hidden: true });
  const body = h(
    "div",
    { class: "form-grid job-form" },
    zone,
    chosen,
    h(
      "div",
      { class: "job-form-grid" },
      field(t("jobform.copies"), input("quantity", { type: "number", min: "1", max: "10000", step: "1", value: "1", required: true })),
      field(t("jobform.material"), input("material", { type: "text", maxlength: "32", list: "job-materials", placeholder: t("jobform.any") })),
      field(t("jobform.nozzle"), input("nozzle", { type: "number", min: "0.05", max: "5", step: "0.05", placeholder: t("jobform.any") })),
      field(t("jobform.priority"), input("priority", { type: "number", min: "-1000", max: "1000", step: "1", value: "0" }), t("jobform.priority_hint")),
      field(t("jobform.printer"), printer),
    ),
    h(
      "details",
      { class: "caps" },
      h("summary", { text: t("jobform.more") }),
      h(
        "div",
        { class: "job-form-grid" },
        field(t("jobform.model"), input("model", { type: "text", maxlength: "100", list: "job-models", placeholder: t("jobform.any") })),
        field(t("jobform.tags"), input("tags", { type: "text", placeholder: "petg, room-b" }), t("form.tags_hint")),
        field(t("jobform.not_before"), input("not_before", { type: "datetime-local" })),
        field(t("jobform.max_attempts"), input("max_attempts", { type: "number", min: "1", max: "100", step: "1", value: "3" })),
      ),
      h("label", { class: "check" }, mismatch, h("span", { text: t("jobform.allow_mismatch") })),
    ),
    materials,
    models,
    progress,
    error,
  );
  const showError = (message, reasons = []) => {
    const list = h("ul", { class: "reason-list" }, reasons.map((r) => h("li", { class: "reason block", text: reasonText(r) })));
    // (replaceChildren writes a null as the text "null")
    error.replaceChildren(h("p", { text: message }), ...(reasons.length ? [list] : []));
    error.hidden = false;
  };
  await modal({
    title: t("jobform.title"),
    body,
    wide: true,
    buttons: [
      { label: t("action.close"), cancel: true },
      { label: t("jobform.submit"), value: "add", kind: "primary" },
    ],
    onSubmit: async (_value, form) => {
      if (!file) {
        showError(t("upload.none_chosen"));
        return false;
      }
      error.hidden = true;
      progress.hidden = false;
      sending = uploadJob(file, fieldsOf(form.elements), {
        onProgress: (fraction) => {
          bar.style.width = `${Math.round(fraction * 100)}%`;
          progress.setAttribute("aria-valuenow", String(Math.round(fraction * 100)));
        },
      });
      try {
        const job = await sending.promise;
        toast({ kind: "ok", message: t("done.add_job", { n: job.quantity, name: job.file.name }) });
        refreshQueue(0);
        return "added";
      } catch (err) {
        progress.hidden = true;
        // Refused by the queue's rules (their reasons listed), or some other failure.
        const refused = err instanceof ApiError && err.code === "invalid_input" && err.reasons.length ? err.reasons : null;
        showError(refused ? t("jobform.refused") : messageOf(err), refused || []);
        return false;
      } finally {
        sending = null;
      }
    },
  });
  // Closed while uploading (onSubmit sets `sending`, which TypeScript's flow analysis
  // does not follow into the callback: it would take it for still null here).
  /** @type {import("./api.js").Upload | null} */ (sending)?.abort();
}

/** The form's values as the API's fields (empty ones left out). */
function fieldsOf(elements) {
  const value = (name) => elements[name].value.trim();
  const when = value("not_before");
  return {
    quantity: value("quantity"),
    priority: value("priority"),
    material: value("material"),
    nozzle: value("nozzle"),
    printer: value("printer"),
    model: value("model"),
    tags: value("tags").split(/[,\s]+/).filter(Boolean),
    // datetime-local is the browser's local time: sent with its offset, as the API asks.
    not_before: when ? new Date(when).toISOString() : "",
    max_attempts: value("max_attempts"),
    allow_mismatch: elements.allow_mismatch.checked ? "true" : "",
  };
}
