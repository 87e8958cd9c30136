// A printer's files: size, date and estimated time (metadata fetched lazily, only for the
// rows on screen), print or delete a file, and drag-and-drop upload with a progress bar.
import { confirmWarnings, startPrint, warningsOf } from "./actions.js";
import { api } from "./api.js";
import { confirmDialog, toast } from "./dialogs.js";
import { h, icon, setHidden } from "./dom.js";
import * as fmt from "./format.js";
import { messageOf, t } from "./i18n.js";
import { can } from "./session.js";
import { printers } from "./store.js";
import { dropZone, uploadFailure, uploadTo } from "./uploads.js";

const PAGE = 100;
const META_PARALLEL = 3;
/** Characters of a file name kept whole when it is cut ("…e_10mm_petg.gcode"). */
const TAIL = 18;
let state = null; // {id, panel, files, shown, observer, queue, active, body}
/** @type {WeakMap<Element, (meta: Record<string, any>) => void>} a file's row -> fills in its metadata */
const fillers = new WeakMap();

// The printer page's wider list adds what a slicer wrote into each file.
const SLICER_COLUMNS = [
  ["c-mat", "files.material"],
  ["c-nozzle", "files.nozzle"],
  ["c-layer", "files.layer"],
];
const SORTS = {
  modified: (a, b) => b.modified - a.modified,
  name: (a, b) => a.path.localeCompare(b.path),
  size: (a, b) => b.size - a.size,
};

/** Fill `panel` with printer `id`'s files and the upload zone; `wide` adds the slicer's
 * material, nozzle and layer height columns. */
export function showFiles(panel, id, { wide = false } = {}) {
  state?.observer?.disconnect();
  const filter = h("input", { type: "search", class: "files-filter", placeholder: t("files.filter"), "aria-label": t("files.filter") });
  const refresh = h("button", { type: "button", class: "btn small", onclick: () => load() }, icon("refresh"), h("span", { text: t("files.refresh") }));
  const sort = h(
    "select",
    { class: "files-sort", "aria-label": t("files.sort") },
    Object.keys(SORTS).map((key) => h("option", { value: key, text: t(`files.sort_${key}`) })),
  );
  sort.addEventListener("change", () => render(PAGE));
  const startBox = h("input", { type: "checkbox" });
  const bar = h("span", { class: "bar" });
  const progress = h("div", { class: "progress", role: "progressbar", "aria-valuemin": "0", "aria-valuemax": "100", "aria-valuenow": "0", "aria-label": t("upload.progress"), hidden: true }, bar);
  const status = h("p", { class: "upload-status", role: "status" });
  const { zone } = dropZone((files) => uploadHere(files[0]));
  const body = h("tbody");
  const table = h(
    "table",
    { class: "files-table" },
    h(
      "thead",
      {},
      h(
        "tr",
        {},
        [["c-file", "files.name"], ["c-size", "files.size"], ["c-date", "files.modified"], ["c-est", "files.estimated"], ...(wide ? SLICER_COLUMNS : []), ["c-print", "files.actions"]].map(([cls, key]) =>
          h("th", { scope: "col", class: cls }, cls === "c-print" ? h("span", { class: "visually-hidden", text: t(key) }) : t(key)),
        ),
      ),
    ),
    body,
  );
  const more = h("button", { type: "button", class: "btn small ghost", hidden: true, text: t("files.more"), onclick: () => render(state.shown + PAGE) });
  const message = h("p", { class: "files-message", role: "status" });
  panel.replaceChildren(
    h("div", { class: "upload-box", hidden: !can("operator") }, zone, h("label", { class: "check" }, startBox, h("span", { text: t("upload.start_after") })), progress, status),
    h("div", { class: "files-toolbar" }, filter, sort, refresh),
    message,
    h("div", { class: "table-scroll" }, table),
    more,
  );
  const observer = new IntersectionObserver(onVisible, { root: panel.closest(".drawer-body") || null });
  state = { id, panel, files: [], shown: 0, observer, queue: [], active: 0, body, more, message, filter, sort, wide, reload: null, meta: new Map() };
  filter.addEventListener("input", () => render(PAGE));
  panel.addEventListener("click", (event) => {
    const print = event.target.closest("button[data-print]");
    if (print) startPrint(id, print.dataset.print);
    const remove = event.target.closest("button[data-delete]");
    if (remove) deleteFile(id, remove.dataset.delete);
  });

  async function uploadHere(file) {
    setHidden(progress, false);
    bar.style.width = "0%";
    status.textContent = t("upload.sending", { filename: file.name });
    const start = startBox.checked;
    const outcome = await uploadTo(id, file, {
      start,
      onProgress: (fraction) => {
        bar.style.width = `${Math.round(fraction * 100)}%`;
        progress.setAttribute("aria-valuenow", String(Math.round(fraction * 100)));
      },
    });
    if (outcome.ok) {
      bar.style.width = "100%";
      status.textContent = outcome.message;
      toast({ kind: "ok", title: printers.get(id)?.name || id, message: outcome.message });
    } else if (outcome.needsConfirm) {
      // Uploaded already (only its start waits for a confirmation): list it, then ask.
      bar.style.width = "100%";
      progress.setAttribute("aria-valuenow", "100");
      status.textContent = t("upload.needs_confirm");
      load();
      if (await confirmWarnings(id, warningsOf(outcome.error))) {
        try {
          await api.act(id, "start", { filename: file.name, confirm: true });
          status.textContent = t("done.upload_start", { filename: file.name });
        } catch (error) {
          status.textContent = messageOf(error);
        }
      } else status.textContent = t("upload.not_started");
    } else {
      if (outcome.uploaded) bar.style.width = "100%";
      status.textContent = uploadFailure(outcome);
      toast({ kind: "error", title: printers.get(id)?.name || id, message: status.textContent });
    }
    load();
  }

  load();
  return filter;
}

/** Delete a file after a confirmation; the list is reloaded from the printer afterwards. */
async function deleteFile(id, path) {
  const name = printers.get(id)?.name || id;
  const ok = await confirmDialog({
    title: t("files.delete_title", { filename: path }),
    message: t("files.delete_body", { name }),
    confirmLabel: t("files.delete"),
    danger: true,
  });
  if (!ok) return;
  try {
    await api.deleteFile(id, path);
    toast({ kind: "ok", title: name, message: t("done.delete_file", { filename: path }) });
  } catch (error) {
    toast({ kind: "error", title: `${name} · ${t("files.delete")}`, message: messageOf(error) });
  }
  if (state?.id !== id) return;
  const hadFocus = state.panel.contains(document.activeElement);
  await load();
  // The button that had the focus is gone with its row: keep the focus in the panel.
  if (hadFocus && state?.id === id && !state.panel.contains(document.activeElement)) state.filter.focus();
}

/** A file name that, when cut, keeps its end: the part that tells `cube_petg_0.2mm.gcode`
 * from `cube_pla_0.2mm.gcode` (the full name on hover, and in the buttons' names). */
function fileName(path) {
  const cut = Math.max(0, path.length - TAIL);
  return h("span", { class: "file-name", title: path }, h("span", { class: "fn-head", text: path.slice(0, cut) }), h("span", { class: "fn-tail", text: path.slice(cut) }));
}

function canStart(id) {
  return can("operator") && Boolean(printers.get(id)?.actions?.start);
}

export function hideFiles() {
  state?.observer?.disconnect();
  clearTimeout(state?.reload);
  state = null;
}

/** The printer's file list changed (an upload, a delete, from anywhere): reload it once
 * the burst is over (an upload of 50 files is 50 notifications). */
export function onFilesChanged(id) {
  const s = state;
  if (!s || s.id !== id) return;
  clearTimeout(s.reload);
  s.reload = setTimeout(() => {
    if (state === s) load();
  }, 500);
}

/** Enable the print buttons only while the printer can start a print. */
export function refreshFileButtons() {
  if (!state) return;
  const allowed = canStart(state.id);
  for (const button of state.body.querySelectorAll("button[data-print]")) button.disabled = !allowed;
  const operator = can("operator");
  for (const button of state.body.querySelectorAll("button[data-delete]")) button.disabled = !operator;
}

async function load() {
  const mine = state;
  if (!mine) return;
  mine.message.textContent = t("files.loading");
  try {
    mine.files = await api.files(mine.id);
  } catch (error) {
    if (state !== mine) return;
    mine.files = [];
    mine.message.textContent = messageOf(error);
    render(0);
    return;
  }
  if (state !== mine) return;
  mine.message.textContent = mine.files.length ? "" : t("files.empty");
  render(PAGE);
}

function render(count) {
  const s = state;
  const words = s.filter.value.trim().toLowerCase();
  const list = (words ? s.files.filter((f) => f.path.toLowerCase().includes(words)) : [...s.files]).sort(SORTS[s.sort.value]);
  s.shown = Math.min(count, list.length);
  s.observer.disconnect();
  s.queue = [];
  const allowed = canStart(s.id);
  const operator = can("operator");
  const rows = list.slice(0, s.shown).map((file) => {
    const estimate = h("td", { class: "c-est" });
    const slicer = s.wide ? SLICER_COLUMNS.map(([cls]) => h("td", { class: cls })) : [];
    const thumb = h("span", { class: "file-thumb" });
    const row = h(
      "tr",
      { dataset: { file: file.path } },
      h("th", { scope: "row", class: "c-file" }, h("span", { class: "file-cell" }, thumb, fileName(file.path))),
      h("td", { class: "c-size", text: fmt.size(file.size) }),
      h("td", { class: "c-date", text: fmt.dateTime(file.modified) }),
      estimate,
      ...slicer,
      h(
        "td",
        { class: "c-print" },
        h(
          "span",
          { class: "file-actions" },
          h("button", { type: "button", class: "btn small primary", dataset: { print: file.path }, disabled: !allowed, "aria-label": t("files.print_named", { filename: file.path }) }, icon("start"), h("span", { text: t("files.print") })),
          h("button", { type: "button", class: "icon-btn small danger", dataset: { delete: file.path }, disabled: !operator, "aria-label": t("files.delete_named", { filename: file.path }), title: t("files.delete") }, icon("remove")),
        ),
      ),
    );
    const fill = (meta) => fillMeta(s.id, file.path, meta, { estimate, thumb, slicer });
    fillers.set(row, fill);
    const known = s.meta.get(`${file.path}|${file.modified}`);
    if (known) fill(known);
    else s.observer.observe(row);
    return row;
  });
  s.body.replaceChildren(...rows);
  setHidden(s.more, s.shown >= list.length);
}

function fillMeta(id, path, meta, { estimate, thumb, slicer }) {
  estimate.textContent = typeof meta.estimated_time === "number" ? fmt.duration(meta.estimated_time) : "—";
  if (slicer.length) {
    const [material, nozzle, layer] = slicer;
    material.textContent = meta.filament_type || "—";
    nozzle.textContent = typeof meta.nozzle_diameter === "number" ? `${meta.nozzle_diameter} mm` : "—";
    layer.textContent = typeof meta.layer_height === "number" ? `${meta.layer_height} mm` : "—";
  }
  const thumbs = (meta.thumbnails || []).filter((x) => x.relative_path).sort((a, b) => a.width - b.width);
  const pick = thumbs.find((x) => x.width >= 32) || thumbs[thumbs.length - 1];
  // Moonraker names a thumbnail relative to its file's folder (the queue's uploads are in
  // kybercore/); the thumbnail route takes a path under gcodes/.
  const folder = path.includes("/") ? path.slice(0, path.lastIndexOf("/") + 1) : "";
  if (pick && !thumb.firstChild) thumb.append(h("img", { src: api.thumbnailUrl(id, folder + pick.relative_path), alt: "", loading: "lazy" }));
}

function onVisible(entries) {
  const s = state;
  if (!s) return;
  for (const entry of entries) {
    if (!entry.isIntersecting) continue;
    s.observer.unobserve(entry.target);
    s.queue.push(entry.target);
  }
  pump(s);
}

/** Fetch metadata a few at a time (a printer with 670 files must not get 670 requests at once). */
function pump(s) {
  while (s.active < META_PARALLEL && s.queue.length) {
    const row = s.queue.shift();
    const path = row.dataset.file;
    const file = s.files.find((f) => f.path === path);
    s.active += 1;
    api
      .metadata(s.id, path)
      .then(
        (meta) => {
          if (file) s.meta.set(`${file.path}|${file.modified}`, meta);
          fillers.get(row)?.(meta);
        },
        () => fillers.get(row)?.({}),
      )
      .finally(() => {
        s.active -= 1;
        if (state === s) pump(s);
      });
  }
}
