// The print's objects on the printer page, as Mainsail's "Exclude objects": a map of the bed
// with each object the slicer labelled, the one printing now marked, and a button to
// exclude one. Excluding asks first (Klipper skips the object for the rest of the print,
// and nothing brings it back); it is EXCLUDE_OBJECT through the console's validated
// G-code route, so it is logged there with Klipper's answer. Shown while a print runs.
import { api } from "./api.js";
import { consoleCommand } from "./console.js";
import { confirmDialog, toast } from "./dialogs.js";
import { h, setAttr, setHidden, setText, svgEl } from "./dom.js";
import { messageOf, t } from "./i18n.js";
import { can } from "./session.js";

/** How often the objects are read again while a print runs (the one printing changes). */
const READ_EVERY_MS = 3000;

/** The card of printer `id` (`.el`, `.update(p)`); `card` is the page's card frame. */
export class ObjectsCard {
  constructor(id, card) {
    this.id = id;
    this.name = id;
    /** @type {{available: boolean, objects: any[], excluded: string[], current: string | null} | null} */
    this.data = null;
    this.file = null;
    this.readAt = 0;
    this.reading = false;
    this.names = null;
    /** @type {Map<string, {el: HTMLElement, state: HTMLElement, button: HTMLButtonElement}>} */
    this.rows = new Map();
    this.map = svgEl("svg", { class: "pp-objects-map", role: "img", "aria-label": t("pp.objects.map") });
    this.list = h("ul", { class: "pp-objects-list" });
    this.mapBox = h("div", { class: "pp-objects-mapbox" }, this.map); // SVG has no `hidden`
    this.note = h("p", { class: "pp-hint", role: "note" });
    this.el = card("pp-objects", t("pp.objects"), h("div", { class: "pp-objects-body" }, this.mapBox, this.list), this.note);
    this.el.hidden = true;
  }

  /** @param {Record<string, any>} p */
  update(p) {
    this.name = p.name;
    const job = p.job || {};
    const running = p.connection === "online" && p.klippy_state === "ready" && ["printing", "paused"].includes(job.state);
    if (!running) {
      this.el.hidden = true;
      this.data = null;
      this.file = null;
      return;
    }
    if (job.filename !== this.file || Date.now() - this.readAt > READ_EVERY_MS) {
      this.file = job.filename;
      this.read(p);
    }
  }

  async read(p) {
    if (this.reading) return;
    this.reading = true;
    this.readAt = Date.now();
    let problem = "";
    try {
      this.data = await api.printObjects(this.id);
    } catch (error) {
      problem = messageOf(error);
    } finally {
      this.reading = false;
    }
    if (this.file !== null) this.render(p, problem);
  }

  /** Show what was last read; `problem`: why the latest read failed, if it did. */
  render(p, problem) {
    const data = this.data || { available: true, objects: [], excluded: [], current: null };
    const objects = data.objects;
    this.el.hidden = false;
    if (problem) setText(this.note, problem);
    else if (!data.available) setText(this.note, t("pp.objects.unavailable"));
    else setText(this.note, objects.length ? "" : t("pp.objects.none"));
    setHidden(this.mapBox, !objects.length);
    const excluded = new Set(/** @type {string[]} */ (data.excluded));
    this.drawMap(p, objects, excluded, data.current);
    // The rows are built once per set of objects and then updated in place, so a keyboard
    // user's focus stays on its button while the object printing now changes.
    const names = objects.map((o) => o.name).join("\n");
    if (names !== this.names) {
      this.names = names;
      this.rows = new Map(objects.map((o) => [o.name, this.row(o.name)]));
      this.list.replaceChildren(...[...this.rows.values()].map((row) => row.el));
    }
    const operator = can("operator");
    for (const [name, row] of this.rows) {
      const out = excluded.has(name);
      const now = !out && name === data.current;
      row.el.className = out ? "is-excluded" : now ? "is-current" : "";
      setText(row.state, out ? t("pp.objects.excluded") : now ? t("pp.objects.current") : "");
      row.button.disabled = out || !operator;
      setAttr(row.button, "title", operator ? null : `${t("pp.objects.exclude")} — ${t("session.needs_operator")}`);
    }
  }

  row(name) {
    const state = h("span", { class: "pp-object-state" });
    const button = h("button", {
      type: "button",
      class: "btn small danger",
      text: t("pp.objects.exclude"),
      "aria-label": t("pp.objects.exclude_one", { object: name }),
      onclick: () => this.exclude(name),
    });
    const el = h("li", { dataset: { object: name } }, h("span", { class: "pp-object-name", text: name }), state, button);
    return { el, state, button };
  }

  /** The bed (its size from the printer's limits) seen from above, front at the bottom. */
  drawMap(p, objects, excluded, current) {
    const volume = p.capabilities?.build_volume || {};
    const width = volume.x || 250;
    const depth = volume.y || 250;
    this.map.setAttribute("viewBox", `0 0 ${width} ${depth}`);
    const shapes = objects.map((o) => {
      const cls = excluded.has(o.name) ? "excluded" : o.name === current ? "current" : "";
      const shape = o.polygon.length >= 3 ? svgEl("polygon", { points: o.polygon.map(([x, y]) => `${x},${depth - y}`).join(" ") }) : o.center ? svgEl("circle", { cx: o.center[0], cy: depth - o.center[1], r: Math.max(width, depth) / 60 }) : null;
      if (!shape) return null;
      shape.setAttribute("class", cls);
      const title = svgEl("title");
      title.textContent = o.name;
      shape.append(title);
      return shape;
    });
    this.map.replaceChildren(svgEl("rect", { class: "bed", x: 0, y: 0, width, height: depth }), ...shapes.filter(Boolean));
  }

  async exclude(object) {
    const yes = await confirmDialog({
      title: t("pp.objects.confirm_title", { object, name: this.name }),
      message: t("pp.objects.confirm"),
      confirmLabel: t("pp.objects.confirm_label"),
      danger: true,
    });
    if (!yes) return;
    const { ok, problem } = await consoleCommand(this.id, `EXCLUDE_OBJECT NAME=${object}`);
    if (ok) toast({ kind: "ok", title: this.name, message: t("pp.objects.done", { object }) });
    else if (problem) toast({ kind: "error", title: this.name, message: problem });
    this.readAt = 0; // read again at the next update: the list shows it excluded
  }
}
