// Uploads with a progress bar (XMLHttpRequest), to one printer or to several at once, with
// an optional print right after and staggered starts (a room preheating at once trips breakers).
import { confirmWarnings, warningsOf } from "./actions.js";
import { ApiError, api, upload } from "./api.js";
import { modal, toast } from "./dialogs.js";
import { h, icon } from "./dom.js";
import * as fmt from "./format.js";
import { messageOf, t } from "./i18n.js";
import { printers } from "./store.js";

const PARALLEL = 4;

/**
 * Upload one file to one printer (and print it when start). Resolves {ok, message, result}
 * or {ok: false, uploaded, error, needsConfirm}. With uploaded the file is stored and only
 * its start was refused (the backend answers 201 with started: false and the start's
 * reasons); when that start needs a confirmation, start it with api.act(..., {confirm: true}).
 * @param {string} id
 * @param {File} file
 * @param {{start?: boolean, onProgress?: (fraction: number) => void}} [options]
 */
export async function uploadTo(id, file, { start = false, onProgress } = {}) {
  let result;
  try {
    result = await upload(id, file, { start, onProgress }).promise;
  } catch (error) {
    return { ok: false, uploaded: false, error, needsConfirm: false };
  }
  if (result.started === false) {
    const error = new ApiError(result.start.status, result.start);
    return { ok: false, uploaded: true, result, error, needsConfirm: error.code === "confirmation_required" };
  }
  return { ok: true, result, message: start ? t("done.upload_start", { filename: file.name }) : t("done.upload", { filename: file.name }) };
}

/** What to say about a failed upload: the reason, after "stored, not started" when it was. */
export function uploadFailure(outcome) {
  const reason = messageOf(outcome.error);
  return outcome.uploaded ? t("upload.stored_not_started", { reason }) : reason;
}

/** A drop zone with a file input inside (click, keyboard, or drag and drop). */
export function dropZone(onFiles, { multiple = false } = {}) {
  const input = h("input", { type: "file", accept: ".gcode,.g,.gco,.ufp", class: "visually-hidden", multiple });
  const zone = h(
    "label",
    { class: "drop-zone" },
    input,
    icon("upload"),
    h("span", { class: "drop-title", text: t("upload.drop") }),
    h("span", { class: "drop-hint", text: t("upload.or_choose") }),
  );
  input.addEventListener("change", () => {
    if (input.files?.length) onFiles([...input.files]);
    input.value = "";
  });
  zone.addEventListener("dragover", (event) => {
    event.preventDefault();
    zone.classList.add("over");
  });
  zone.addEventListener("dragleave", () => zone.classList.remove("over"));
  zone.addEventListener("drop", (event) => {
    event.preventDefault();
    zone.classList.remove("over");
    if (event.dataTransfer?.files.length) onFiles([...event.dataTransfer.files]);
  });
  return { zone, input };
}

function progressRow(id) {
  const bar = h("span", { class: "bar" });
  const progress = h("div", { class: "progress", role: "progressbar", "aria-valuemin": "0", "aria-valuemax": "100", "aria-valuenow": "0", "aria-label": t("upload.progress_of", { name: printers.get(id)?.name || id }) }, bar);
  const status = h("span", { class: "row-status", text: t("upload.waiting") });
  const row = h("li", { class: "upload-row", dataset: { printer: id } }, h("span", { class: "row-name", text: printers.get(id)?.name || id }), progress, status);
  return {
    row,
    progress(fraction) {
      bar.style.width = `${Math.round(fraction * 100)}%`;
      progress.setAttribute("aria-valuenow", String(Math.round(fraction * 100)));
      status.textContent = fmt.percent(fraction);
    },
    done(kind, text) {
      row.classList.remove("ok", "warn", "fail");
      row.classList.add(kind);
      if (kind === "ok") this.progress(1);
      status.textContent = text;
    },
  };
}

/** Upload one file to several printers, each with its own progress bar and result. */
export async function uploadDialog(ids, initialFiles = []) {
  let file = initialFiles[0] || null;
  let finished = false;
  const chosen = h("p", { class: "chosen-file" });
  const showChosen = () => {
    chosen.textContent = file ? `${file.name} · ${fmt.size(file.size)}` : t("upload.none_chosen");
  };
  showChosen();
  const { zone } = dropZone((files) => {
    file = files[0];
    showChosen();
  });
  const startBox = h("input", { type: "checkbox", name: "start" });
  const stagger = h("input", { type: "number", name: "stagger", min: "0", max: "600", step: "1", value: "0" });
  const rows = new Map(ids.map((id) => [id, progressRow(id)]));
  const error = h("p", { class: "form-error", role: "alert", hidden: true });
  const body = h(
    "div",
    { class: "form-grid" },
    zone,
    chosen,
    h("label", { class: "check" }, startBox, h("span", { text: t("upload.start_after") })),
    ids.length > 1 ? h("label", { class: "field inline" }, h("span", { text: t("upload.stagger") }), stagger) : null,
    h("ul", { class: "upload-list", "aria-label": t("upload.targets") }, [...rows.values()].map((r) => r.row)),
    error,
  );
  await modal({
    title: ids.length === 1 ? t("upload.title_one", { name: printers.get(ids[0])?.name || ids[0] }) : t("upload.title_many", { n: ids.length }),
    body,
    wide: true,
    buttons: [
      { label: t("action.close"), cancel: true },
      { label: t("upload.go"), value: "upload", kind: "primary" },
    ],
    onSubmit: async (_value, form) => {
      if (finished) return "done";
      if (!file) {
        error.textContent = t("upload.none_chosen");
        error.hidden = false;
        return false;
      }
      error.hidden = true;
      const start = startBox.checked;
      const delay = start ? Math.max(0, Number(stagger.value) || 0) * 1000 : 0;
      await uploadMany(ids, file, { start, delay, rows });
      finished = true;
      const submit = /** @type {HTMLButtonElement} */ (form.querySelector("button[type=submit]"));
      submit.textContent = t("action.done");
      return false;
    },
  });
}

async function uploadMany(ids, file, { start, delay, rows }) {
  // With a pace, the files go up first and the server starts them one by one: it keeps
  // the pace even if this page is closed.
  const paced = start && delay > 0 && ids.length > 1;
  /** @type {{id: string, error: unknown}[]} */
  const needConfirm = [];
  /** @type {string[]} */
  const stored = [];
  /** @param {string} id */
  const one = async (id) => {
    const row = rows.get(id);
    const outcome = await uploadTo(id, file, { start: start && !paced, onProgress: (f) => row.progress(f) });
    if (outcome.ok && paced) {
      stored.push(id);
      row.done("warn", t("upload.waiting_start"));
    } else if (outcome.ok) row.done("ok", outcome.message);
    else if (outcome.needsConfirm) {
      needConfirm.push({ id, error: outcome.error });
      row.progress(1); // uploaded; only the start waits for a confirmation
      row.done("warn", t("upload.needs_confirm"));
    } else if (outcome.uploaded) {
      row.progress(1); // stored; only the start was refused
      row.done("warn", uploadFailure(outcome));
    } else row.done("fail", uploadFailure(outcome));
  };
  const queue = [...ids];
  await Promise.all(Array.from({ length: Math.min(PARALLEL, queue.length) }, async () => {
    while (queue.length) await one(queue.shift());
  }));
  /**
   * Start the stored file on printers, paced by the server when asked to.
   * @param {string[]} targets
   * @param {boolean} confirm
   */
  const startOn = async (targets, confirm) => {
    if (!targets.length) return;
    const pace = paced ? delay / 1000 : 0;
    let results;
    try {
      ({ results } = await api.actMany("start", targets, { filename: file.name, confirm, stagger_seconds: pace }));
    } catch (err) {
      for (const id of targets) rows.get(id).done("fail", messageOf(err));
      return;
    }
    for (const result of results) {
      const row = rows.get(result.printer_id);
      if (result.ok) row.done("ok", t("done.upload_start", { filename: file.name }));
      else if (result.code === "confirmation_required" && !confirm) {
        needConfirm.push({ id: result.printer_id, error: new ApiError(result.status, result) });
        row.done("warn", t("upload.needs_confirm"));
      } else row.done("warn", t("upload.stored_not_started", { reason: messageOf(new ApiError(result.status, result)) }));
    }
  };
  if (paced) await startOn(ids.filter((id) => stored.includes(id)), false);
  const confirmed = [];
  for (const { id, error } of needConfirm) {
    if (await confirmWarnings(id, warningsOf(error))) confirmed.push(id);
    else rows.get(id).done("warn", t("upload.not_started"));
  }
  await startOn(confirmed, true);
  // A file stored but not started (warn) is not done either: the user asked for a print.
  const failures = ids.filter((id) => !rows.get(id).row.classList.contains("ok")).length;
  toast({
    kind: failures ? "error" : "ok",
    title: t("upload.title_many", { n: ids.length }),
    message: t("upload.summary", { ok: ids.length - failures, n: ids.length }),
    timeout: 6000,
  });
}
