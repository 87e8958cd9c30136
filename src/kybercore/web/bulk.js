// Bulk actions on the selected printers: a dry run per printer first (what would happen on
// each), then the action, then one real result per printer.
import { CONFIRM, doneText, temperatureDialog } from "./actions.js";
import { api } from "./api.js";
import { modal, toast } from "./dialogs.js";
import { h, icon, setHidden, setText } from "./dom.js";
import { messageOf, reasonText, t } from "./i18n.js";
import { clearSelection, selectGroup, selectWhere, selection } from "./overview.js";
import { can } from "./session.js";
import { printers } from "./store.js";
import { uploadDialog } from "./uploads.js";

const ACTIONS = [
  ["pause", "pause"],
  ["resume", "resume"],
  ["cancel", "cancel"],
  ["home", "home"],
  ["set_temperature", "temp"],
  ["start", "start"],
  ["firmware_restart", "chip"],
  ["restart", "restart"],
];

let bar = null;
let countEl = null;

/** Build the bulk bar (shown while printers are selected) and the "select" shortcuts. */
export function initBulk(barEl, selectButtons) {
  bar = barEl;
  countEl = h("strong", { class: "bulk-count", "aria-live": "polite" });
  const button = (action, iconName, extra = "") =>
    h(
      "button",
      { type: "button", class: `btn small ${extra}`.trim(), dataset: { bulk: action, i18nTitle: `bulk.title.${action}` } },
      icon(iconName),
      h("span", { dataset: { i18n: `bulk.short.${action}` } }),
    );
  bar.append(
    countEl,
    h("div", { class: "bulk-actions", role: "group", dataset: { i18nAriaLabel: "bulk.actions" }, "aria-label": t("bulk.actions") }, ACTIONS.map(([action, iconName]) => button(action, iconName))),
    button("upload", "upload"),
    button("emergency_stop", "bolt", "estop"),
    button("clear", "close", "ghost"),
  );
  bar.addEventListener("click", (event) => {
    const button = event.target.closest("[data-bulk]");
    if (!button) return;
    const action = button.dataset.bulk;
    if (action === "clear") clearSelection();
    else if (action === "upload") uploadDialog([...selection]);
    else bulkAction(action);
  });
  for (const button of selectButtons) {
    button.addEventListener("click", () => {
      const which = button.dataset.selectGroup;
      if (which === "all") selectWhere(() => true);
      else if (which === "none") clearSelection();
      else selectGroup(which);
    });
  }
  updateBulkBar();
}

export function updateBulkBar() {
  if (!bar) return;
  const n = selection.size;
  setHidden(bar, n === 0);
  setText(countEl, t("bulk.selected", { n }));
  const operator = can("operator");
  for (const button of bar.querySelectorAll("[data-bulk]")) {
    if (button.dataset.bulk !== "clear") button.disabled = !operator;
  }
}

const nameOf = (id) => printers.get(id)?.name || id;

function resultList(rows) {
  return h(
    "ul",
    { class: "result-list" },
    rows.map((row) =>
      h(
        "li",
        { class: `result ${row.kind}`, dataset: { printer: row.id } },
        h("span", { class: "result-icon", "aria-hidden": "true" }, icon(row.kind === "ok" ? "check" : "alert")),
        h("strong", { class: "result-name", text: nameOf(row.id) }),
        row.badge ? h("span", { class: "result-badge", text: row.badge }) : null,
        h("span", { class: "result-text", text: row.text }),
      ),
    ),
  );
}

/** Ask for a file name that exists on the printers (suggestions from the first one). */
async function chooseFile(ids) {
  const listId = "bulk-files";
  const input = h("input", { type: "text", name: "filename", list: listId, required: true, autocomplete: "off" });
  const options = h("datalist", { id: listId });
  api.files(ids[0]).then(
    (files) => options.replaceChildren(...files.slice(0, 500).map((f) => h("option", { value: f.path }))),
    () => {},
  );
  const error = h("p", { class: "form-error", role: "alert", hidden: true });
  let filename = null;
  await modal({
    title: t("bulk.start_title", { n: ids.length }),
    body: h("div", { class: "form-grid" }, h("label", { class: "field" }, h("span", { text: t("files.name") }), input, options), h("p", { class: "hint", text: t("bulk.start_hint") }), error),
    buttons: [
      { label: t("action.back"), cancel: true },
      { label: t("action.next"), value: "next", kind: "primary" },
    ],
    onSubmit: () => {
      filename = input.value.trim();
      if (filename) return "next";
      error.textContent = t("bulk.need_file");
      error.hidden = false;
      return false;
    },
  });
  return filename;
}

/** Dry run on every selected printer, then run, then show one result per printer. */
export async function bulkAction(action) {
  const ids = [...selection];
  if (!ids.length) return;
  const label = t(`action.${action}`);
  /** @type {Record<string, unknown>} */
  let params = {};
  if (action === "set_temperature") {
    const targets = await temperatureDialog(ids, { sendIt: false });
    if (!targets) return;
    params = targets;
  }
  if (action === "start") {
    const filename = await chooseFile(ids);
    if (!filename) return;
    params = { filename };
  }
  let checks;
  try {
    checks = (await api.checkMany(action, ids, params)).results;
  } catch (error) {
    toast({ kind: "error", title: label, message: messageOf(error) });
    return;
  }
  const warned = checks.some((c) => c.level === "warn");
  const blocked = checks.filter((c) => c.level === "block").length;
  const preview = resultList(
    checks.map((c) => ({
      id: c.printer_id,
      kind: c.level,
      badge: t(`check.${c.level}`),
      text: c.reasons.filter((r) => r.level !== "ok").map(reasonText).join(" ") || t("check.ok_text"),
    })),
  );
  const runnable = ids.length - blocked;
  const note = runnable === 0 ? t("bulk.none_can", { n: ids.length }) : blocked ? t("bulk.some_blocked", { n: blocked, ok: runnable }) : warned ? t("bulk.some_warn") : t("bulk.all_ok");
  const summary = h("p", { class: runnable === 0 ? "form-error" : "", text: note });
  /** @type {import("./dialogs.js").DialogButton[]} */
  const buttons = [{ label: t("action.back"), cancel: true }];
  // Nothing to run when every printer refuses: no button that would only fail N times.
  if (runnable > 0) {
    const kind = CONFIRM.has(action) || action === "emergency_stop" ? "danger" : "primary";
    buttons.push({ label: t("bulk.run", { action: label, n: runnable }), value: "run", kind });
  }
  const go = await modal({ title: t("bulk.preview_title", { action: label, n: ids.length }), body: h("div", {}, summary, preview), wide: true, buttons });
  if (go !== "run") return;
  let results;
  try {
    // Only the printers the dry run cleared: the refusals were shown, with their reasons.
    const targets = checks.filter((c) => c.level !== "block").map((c) => c.printer_id);
    results = (await api.actMany(action, targets, { ...params, confirm: warned })).results;
  } catch (error) {
    toast({ kind: "error", title: label, message: messageOf(error) });
    return;
  }
  const failures = results.filter((r) => !r.ok).length;
  await modal({
    title: t("bulk.results_title", { action: label }),
    wide: true,
    body: h(
      "div",
      {},
      h("p", { text: t("bulk.results_summary", { ok: results.length - failures, n: results.length }) }),
      resultList(
        results.map((r) => ({
          id: r.printer_id,
          kind: r.ok ? "ok" : "fail",
          badge: r.ok ? t("check.done") : `${r.status} · ${r.code}`,
          text: r.ok ? doneText(action, params) : messageOf(r),
        })),
      ),
    ),
    buttons: [{ label: t("action.close"), value: "close", kind: "primary" }],
  });
}
