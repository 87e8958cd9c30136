// The printer page's print card, Mainsail's "status" panel: the file with its thumbnail,
// progress, time left and finish clock, layer and print time; pause, resume and cancel;
// and the plate gate (Good / Bad…) once the print is over. The same helpers as the tiles,
// so both say the same thing, and every button goes through the tiles' action handler.
import { onCardAction } from "./actions.js";
import { api } from "./api.js";
import { doneText, hasJob, layerText, noteOf, progressBar, setEta, setProgress } from "./cards.js";
import { h, icon, setAttr, setHidden, setText } from "./dom.js";
import * as fmt from "./format.js";
import { t } from "./i18n.js";
import { GateStrip } from "./gates.js";
import { can } from "./session.js";

const BUTTONS = [
  ["pause", "pause", ""],
  ["resume", "resume", ""],
  ["cancel", "cancel", "danger"],
];

/** The card for printer `id`: {el, update(p)}; build it again on a language change. */
export function jobCard(id, card) {
  const refs = {
    thumb: h("img", { class: "pp-job-thumb", alt: "", hidden: true }),
    file: h("p", { class: "pp-job-file" }),
    progress: progressBar(),
    pct: h("span", { class: "pct" }),
    eta: h("span", { class: "eta" }),
    done: h("span", { class: "done" }),
    layer: h("span", { class: "layer" }),
    time: h("span", { class: "pp-job-time" }),
    note: h("p", { class: "note", hidden: true }),
    gate: new GateStrip(),
    buttons: BUTTONS.map(([action, iconName, extra]) =>
      h("button", { type: "button", class: `btn small ${extra}`.trim(), dataset: { action } }, icon(iconName), h("span", { text: t(`action.${action}`) })),
    ),
  };
  refs.thumb.addEventListener("error", () => (refs.thumb.hidden = true));
  setAttr(refs.progress, "aria-label", t("job.progress"));
  const el = card(
    "pp-job",
    t("pp.job"),
    h(
      "div",
      { class: "pp-job-body" },
      refs.thumb,
      h("div", { class: "pp-job-main" }, refs.file, refs.progress, h("p", { class: "job-meta" }, refs.pct, refs.eta, refs.done, refs.layer, refs.time))
    ),
    refs.note,
    refs.gate.el,
    h("div", { class: "pp-row" }, ...refs.buttons),
  );
  el.addEventListener("click", async (event) => {
    const button = /** @type {HTMLElement} */ (event.target).closest("button[data-action]");
    if (!(button instanceof HTMLButtonElement) || button.disabled) return;
    button.classList.add("busy");
    try {
      await onCardAction(id, button.dataset.action || "", button);
    } finally {
      button.classList.remove("busy");
    }
  });
  let thumbKey = "";
  return {
    el,
    /** @param {Record<string, any>} p */
    update(p) {
      const job = p.job || {};
      const present = hasJob(p);
      setText(refs.file, present ? fmt.baseName(job.filename) : t("job.none"));
      setAttr(refs.file, "title", present ? job.filename : null);
      setProgress(refs.progress, present ? job.progress : 0);
      setText(refs.pct, present ? fmt.percent(job.progress) : "");
      setEta(refs.eta, present ? job : {});
      setText(refs.done, present ? doneText(job) : "");
      setText(refs.layer, present ? layerText(job) : "");
      const seconds = present && job.print_duration > 0 ? job.print_duration : null;
      setText(refs.time, seconds === null ? "" : t("pp.print_time", { time: fmt.duration(seconds) }));
      const path = present && p.connection === "online" ? job.thumbnail : null;
      if ((path || "") !== thumbKey) {
        thumbKey = path || "";
        setHidden(refs.thumb, !path);
        if (path) refs.thumb.src = api.thumbnailUrl(p.id, path);
        else refs.thumb.removeAttribute("src");
      }
      const note = noteOf(p);
      setText(refs.note, note);
      setHidden(refs.note, !note);
      refs.gate.update(p, el);
      const operator = can("operator");
      const actions = p.actions || {};
      for (const button of refs.buttons) {
        const action = button.dataset.action || "";
        button.disabled = !operator || !actions[action];
        const label = t(`action.${action}`);
        setAttr(button, "aria-label", t("aria.onPrinter", { action: label, name: p.name }));
        setAttr(button, "title", operator ? label : `${label} — ${t("session.needs_operator")}`);
      }
    },
  };
}
