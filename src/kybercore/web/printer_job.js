// The printer page's print card, Mainsail's "status" panel: the file with its thumbnail,
// progress, time left and finish clock, layer and print time; pause, resume and cancel;
// the age of its data when the printer has gone quiet; and the plate gate (Good / Bad…)
// once the print is over. Built from the tiles' parts, so both say the same thing, and
// every button goes through the tiles' action handler.
import { onCardButton } from "./actions.js";
import { api } from "./api.js";
import { Card, hasJob, JobMeta, noteOf, progressBar, setProgress } from "./cards.js";
import { h, icon, setAttr, setHidden, setText } from "./dom.js";
import * as fmt from "./format.js";
import { t } from "./i18n.js";
import { GateStrip } from "./gates.js";
import { can } from "./session.js";
import { serverNow } from "./store.js";

const BUTTONS = [
  ["pause", "pause", ""],
  ["resume", "resume", ""],
  ["cancel", "cancel", "danger"],
];

/** The card of printer `id` (`.el`, `.update(p)`); build it again on a language change.
 * `card(cls, title, ...children)` is the page's card frame. */
export class JobCard extends Card {
  constructor(id, card) {
    super(id);
    const time = h("span", { class: "pp-job-time" });
    const r = (this.refs = {
      thumb: h("img", { class: "pp-job-thumb", alt: "", hidden: true }),
      file: h("p", { class: "pp-job-file" }),
      progress: progressBar(),
      jobMeta: new JobMeta(time),
      time,
      note: h("p", { class: "note", hidden: true }),
      stale: h("p", { class: "stale", hidden: true }),
      gate: new GateStrip(),
      buttons: BUTTONS.map(([action, iconName, extra]) =>
        h("button", { type: "button", class: `btn small ${extra}`.trim(), dataset: { action } }, icon(iconName), h("span", { text: t(`action.${action}`) })),
      ),
    });
    r.thumb.addEventListener("error", () => (r.thumb.hidden = true));
    setAttr(r.progress, "aria-label", t("job.progress"));
    this.el = card(
      "pp-job",
      t("pp.job"),
      h("div", { class: "pp-job-body" }, r.thumb, h("div", { class: "pp-job-main" }, r.file, r.progress, r.jobMeta.el)),
      r.note,
      r.stale,
      r.gate.el,
      h("div", { class: "pp-row" }, ...r.buttons),
    );
    this.el.addEventListener("click", (event) => {
      const button = /** @type {HTMLElement} */ (event.target).closest("button[data-action]");
      if (button instanceof HTMLButtonElement && !button.disabled) onCardButton(id, button.dataset.action || "", button);
    });
  }

  /** @param {Record<string, any>} p */
  update(p) {
    const r = this.refs;
    const job = hasJob(p) ? p.job : null;
    if (this.changed("file", job ? job.filename : "")) {
      setText(r.file, job ? fmt.baseName(job.filename) : t("job.none"));
      setAttr(r.file, "title", job ? job.filename : null);
    }
    setProgress(r.progress, job ? job.progress : 0);
    r.jobMeta.update(job);
    const seconds = job && job.print_duration > 0 ? Math.floor(job.print_duration) : null;
    if (this.changed("time", seconds)) setText(r.time, seconds === null ? "" : t("pp.print_time", { time: fmt.duration(seconds) }));
    this.setThumb(p, job ? job.thumbnail : null);
    const note = noteOf(p);
    if (this.changed("note", note)) {
      setText(r.note, note);
      setHidden(r.note, !note);
    }
    r.gate.update(p, this.el);
    this.updateStale(p, serverNow());
    this.updateButtons(p);
  }

  setThumb(p, path) {
    const usable = path && p.connection === "online" ? path : "";
    if (!this.changed("thumb", usable)) return;
    setHidden(this.refs.thumb, !usable);
    if (usable) this.refs.thumb.src = api.thumbnailUrl(p.id, usable);
    else this.refs.thumb.removeAttribute("src");
  }

  updateButtons(p) {
    const operator = can("operator");
    const actions = p.actions || {};
    const allowed = BUTTONS.map(([action]) => operator && Boolean(actions[action]));
    if (!this.changed("buttons", `${allowed}|${operator}|${p.name}`)) return;
    this.refs.buttons.forEach((button, i) => {
      const action = button.dataset.action || "";
      button.disabled = !allowed[i];
      const label = t(`action.${action}`);
      setAttr(button, "aria-label", t("aria.onPrinter", { action: label, name: p.name }));
      setAttr(button, "title", operator ? label : `${label} — ${t("session.needs_operator")}`);
    });
  }
}
