// One printer as a tile (overview) or a table row (compact view). Each is built once and
// then updated in place: every field is written only when its value changed.
import { api } from "./api.js";
import { h, icon, setAttr, setHidden, setText } from "./dom.js";
import * as fmt from "./format.js";
import { GateStrip } from "./gates.js";
import { t } from "./i18n.js";
import { can, currentSession } from "./session.js";
import { serverNow, staleAge, statusOf } from "./store.js";

/** The active Spoolman spool as a badge: its colour, material and grams left. */
export function showSpool(el, spool) {
  setHidden(el, !spool);
  if (!spool) return;
  const swatch = h("span", { class: "swatch", "aria-hidden": "true" });
  if (spool.color_hex) swatch.style.background = `#${spool.color_hex}`; // CSSOM: the CSP allows it
  const left = typeof spool.remaining_g === "number" ? t("spool.left", { g: Math.round(spool.remaining_g) }) : "";
  el.replaceChildren(swatch, h("span", { text: [spool.material, left].filter(Boolean).join(" · ") }));
  el.title = `${t("spool.title", { id: spool.id })}: ${spool.name}`;
}

/** The printer page's address: every name links there. */
export function pageOf(id) {
  return `#printer/${encodeURIComponent(id)}`;
}

/** Quick actions on every card; the rest live in the "more" menu. */
const QUICK = ["pause", "resume", "cancel"];

function actionButton(action, iconName, extraClass = "") {
  return h("button", { type: "button", class: `icon-btn ${extraClass}`.trim(), dataset: { action } }, icon(iconName));
}

function buildActions() {
  const box = h("div", { class: "card-actions" });
  for (const action of QUICK) box.append(actionButton(action, action));
  box.append(
    h("span", { class: "sep", "aria-hidden": "true" }),
    actionButton("files", "files"),
    actionButton("console", "console"),
    h("button", { type: "button", class: "icon-btn", dataset: { action: "more" }, "aria-haspopup": "menu", "aria-expanded": "false" }, icon("more")),
    h("button", { type: "button", class: "btn estop", dataset: { action: "emergency_stop" } }, icon("bolt"), h("span", { class: "estop-label" })),
  );
  return box;
}

/** Labels and enabled state of the action buttons, from the view's `actions` and the role. */
function updateActions(box, p, memo) {
  const actions = p.actions || {};
  const online = p.connection === "online";
  const operator = can("operator");
  const key = `${JSON.stringify(actions)}|${online}|${p.name}|${currentSession().role}|${t("action.pause")}`;
  if (memo.actions === key) return;
  memo.actions = key;
  for (const button of box.querySelectorAll("[data-action]")) {
    const action = button.dataset.action;
    const label = t(`action.${action}`);
    // The e-stop's name starts with the word it shows (PARAR, STOP): voice control finds it.
    const named = action === "emergency_stop" ? t("aria.estop", { short: t("action.estop_short"), action: label }) : label;
    setAttr(button, "aria-label", t("aria.onPrinter", { action: named, name: p.name }));
    let enabled = true;
    if (action === "files" || action === "console") enabled = online;
    else if (action in actions) enabled = operator && Boolean(actions[action]);
    button.disabled = !enabled;
    setAttr(button, "title", !operator && action in actions ? `${label} — ${t("session.needs_operator")}` : label);
  }
  setText(box.querySelector(".estop-label"), t("action.estop_short"));
}

/** Text of the note line: why a printer is not usable, or the job's message. */
export function noteOf(p) {
  if (p.connection !== "online" && p.connection !== "disabled") return p.connection_error || "";
  if (p.connection === "online" && p.klippy_state !== "ready") return p.klippy_message || "";
  return p.job?.message || "";
}

function heaterText(heater) {
  return fmt.temp(heater?.temperature);
}

function targetText(heater) {
  const value = fmt.target(heater?.target);
  return value ? `/ ${value}` : "";
}

function busy(job) {
  return ["printing", "paused"].includes(job?.state);
}

/** "4 min left"; "—" while the time left is unknown (heating, before any extrusion). */
function etaText(job) {
  if (!busy(job)) return "";
  return typeof job.eta_seconds === "number" ? t("job.left", { time: fmt.duration(job.eta_seconds) }) : "—";
}

/** "done at 15:42" for a busy job, or "". */
function doneText(job) {
  return busy(job) ? fmt.doneText(job, serverNow()) : "";
}

/** The time left (else `otherwise`), with a hint while it is unknown. */
function setEta(el, job, otherwise = "") {
  const text = etaText(job);
  setText(el, text || otherwise);
  setAttr(el, "title", text === "—" ? t("job.eta_pending") : null);
}

function layerText(job) {
  if (typeof job?.layer !== "number" || typeof job?.total_layers !== "number") return "";
  return t("job.layer", { layer: job.layer, total: job.total_layers });
}

export function hasJob(p) {
  return Boolean(p.job?.filename) && p.klippy_state === "ready";
}

export function setProgress(el, fraction) {
  const value = Math.round((fraction || 0) * 1000) / 10;
  setAttr(el, "aria-valuenow", Math.floor(value));
  const bar = el.firstElementChild;
  const width = `${value}%`;
  if (bar.style.width !== width) bar.style.width = width;
}

/** The line under a job's progress bar: percent, time left, finish clock and layer, then
 * whatever `extra` elements a card adds; written whole, or emptied when there is no job. */
export class JobMeta {
  constructor(...extra) {
    this.pct = h("span", { class: "pct" });
    this.eta = h("span", { class: "eta" });
    this.done = h("span", { class: "done" });
    this.layer = h("span", { class: "layer" });
    this.el = h("p", { class: "job-meta" }, this.pct, this.eta, this.done, this.layer, ...extra);
  }

  /** @param {Record<string, any> | null} job the printer's job, or null when it has none */
  update(job) {
    setText(this.pct, job ? fmt.percent(job.progress) : "");
    setEta(this.eta, job || {});
    setText(this.done, job ? doneText(job) : "");
    setText(this.layer, job ? layerText(job) : "");
  }
}

export function progressBar() {
  return h("div", { class: "progress", role: "progressbar", "aria-valuemin": "0", "aria-valuemax": "100", "aria-valuenow": "0" }, h("span", { class: "bar" }));
}

/** What the fleet's tiles and rows and the printer page's cards share: a memo of what they
 * last wrote, so an update of one printer writes only what changed. */
export class Card {
  /** @param {string} id */
  constructor(id) {
    this.id = id;
    /** @type {Record<string, unknown>} */
    this.memo = {};
    /** The card's element and its parts (set by the subclass). @type {HTMLElement} */
    this.el;
    /** @type {{stale: HTMLElement}} */
    this.refs;
  }

  /** True (and remembered) when `value` differs from the last one seen under `key`. */
  changed(key, value) {
    if (this.memo[key] === value) return false;
    this.memo[key] = value;
    return true;
  }

  /** Forget every remembered value: the next update writes everything (language change). */
  reset() {
    this.memo = {};
  }

  updateStale(p, now) {
    const age = staleAge(p, now);
    const text = age === null ? "" : t("stale.age", { age: fmt.age(age) });
    if (this.changed("stale", text)) {
      setText(this.refs.stale, text);
      setHidden(this.refs.stale, !text);
      this.el.classList.toggle("is-stale", Boolean(text));
    }
  }
}

export class Tile extends Card {
  constructor(p) {
    super(p.id);
    const nameId = `tile-${p.id}-name`;
    const r = (this.refs = {
      select: h("input", { type: "checkbox", class: "select", dataset: { select: p.id } }),
      nameLink: h("a", { class: "name-link", href: pageOf(p.id) }),
      meta: h("p", { class: "meta" }),
      pill: h("span", { class: "pill" }),
      conn: h("span", { class: "badge conn" }),
      klippy: h("span", { class: "badge klippy" }),
      limits: h("span", { class: "badge limits", hidden: true }),
      spool: h("span", { class: "badge spool", hidden: true }),
      tags: h("span", { class: "tags" }),
      thumbImg: h("img", { alt: "", decoding: "async", loading: "lazy" }),
      file: h("p", { class: "file" }),
      progress: progressBar(),
      jobMeta: new JobMeta(),
      note: h("p", { class: "note", hidden: true }),
      hotend: h("span", { class: "value" }),
      hotendTarget: h("span", { class: "target" }),
      bed: h("span", { class: "value" }),
      bedTarget: h("span", { class: "target" }),
      hotendLabel: h("span", { class: "label" }),
      bedLabel: h("span", { class: "label" }),
      stale: h("p", { class: "stale", hidden: true }),
      gate: new GateStrip(),
      actions: buildActions(),
    });
    r.name = h("h3", { class: "name", id: nameId }, r.nameLink);
    r.thumbImg.addEventListener("error", () => {
      r.thumbImg.hidden = true;
    });
    r.thumb = h("div", { class: "thumb" }, r.thumbImg, icon("files"));
    this.el = h(
      "article",
      { class: "tile", dataset: { id: p.id }, "aria-labelledby": nameId },
      h("header", { class: "tile-head" }, r.select, h("div", { class: "tile-title" }, r.name, r.meta), r.pill),
      h("div", { class: "badges" }, r.conn, r.klippy, r.limits, r.spool, r.tags),
      h("div", { class: "job" }, r.thumb, h("div", { class: "job-body" }, r.file, r.progress, r.jobMeta.el)),
      r.note,
      r.gate.el,
      h(
        "div",
        { class: "temps" },
        h("div", { class: "temp" }, r.hotendLabel, r.hotend, r.hotendTarget),
        h("div", { class: "temp" }, r.bedLabel, r.bed, r.bedTarget),
      ),
      r.stale,
      r.actions,
    );
  }

  update(p, now) {
    const r = this.refs;
    const status = statusOf(p);
    if (this.changed("name", p.name)) {
      setText(r.nameLink, p.name);
      r.name.title = p.name;
    }
    if (this.changed("nameLabel", `${p.name}|${t("aria.select")}`)) {
      setAttr(r.select, "aria-label", t("aria.select", { name: p.name }));
      setAttr(r.progress, "aria-label", t("aria.progress", { name: p.name }));
    }
    if (this.changed("meta", `${p.model}|${p.location}`)) setText(r.meta, [p.model, p.location].filter(Boolean).join(" · "));
    if (this.changed("status", `${status.group}|${status.key}|${t(status.key)}`)) {
      this.el.dataset.status = status.group;
      setText(r.pill, t(status.key));
    }
    if (this.changed("conn", `${p.connection}|${t("conn." + p.connection)}`)) {
      r.conn.dataset.conn = p.connection;
      setText(r.conn, t(`conn.${p.connection}`));
      r.conn.title = `Moonraker: ${t(`conn.${p.connection}`)}`;
    }
    if (this.changed("klippy", `${p.klippy_state}|${t("klippy." + p.klippy_state)}`)) {
      r.klippy.dataset.klippy = p.klippy_state;
      setText(r.klippy, t(`klippy.${p.klippy_state}`));
    }
    // Limits not known: start, temperatures and G-code are refused until they are.
    const limits = p.connection === "online" && p.limits && p.limits !== "known" ? p.limits : "";
    if (this.changed("limits", `${limits}|${t("limits.unknown")}`)) {
      setHidden(r.limits, !limits);
      if (limits) {
        r.limits.dataset.limits = limits;
        setText(r.limits, t(`limits.${limits}`));
        r.limits.title = t(`limits.${limits}_hint`);
      }
    }
    if (this.changed("tags", (p.tags || []).join("\n"))) {
      r.tags.replaceChildren(...(p.tags || []).map((tag) => h("span", { class: "tag", text: tag })));
    }
    if (this.changed("spool", `${JSON.stringify(p.spool)}|${t("spool.left", { g: 0 })}`)) showSpool(r.spool, p.spool);
    this.updateJob(p);
    const note = noteOf(p);
    if (this.changed("note", note)) {
      setText(r.note, note);
      setHidden(r.note, !note);
    }
    if (this.changed("labels", t("temp.hotend"))) {
      setText(r.hotendLabel, t("temp.hotend"));
      setText(r.bedLabel, t("temp.bed"));
    }
    setText(r.hotend, heaterText(p.extruder));
    setText(r.hotendTarget, targetText(p.extruder));
    setText(r.bed, heaterText(p.bed));
    setText(r.bedTarget, targetText(p.bed));
    /** @type {HTMLElement} */ (r.hotend.parentElement).classList.toggle("heating", (p.extruder?.target || 0) > 0);
    /** @type {HTMLElement} */ (r.bed.parentElement).classList.toggle("heating", (p.bed?.target || 0) > 0);
    r.gate.update(p, this.el);
    this.updateStale(p, now);
    updateActions(r.actions, p, this.memo);
  }

  updateJob(p) {
    const r = this.refs;
    const job = p.job || {};
    const present = hasJob(p);
    this.el.classList.toggle("no-job", !present);
    if (!present) {
      if (this.changed("file", `idle|${t("job.none")}`)) {
        setText(r.file, t("job.none"));
        r.file.removeAttribute("title");
      }
      setProgress(r.progress, 0);
      r.jobMeta.update(null);
      this.setThumb(p, null);
      return;
    }
    if (this.changed("file", job.filename)) {
      setText(r.file, fmt.baseName(job.filename));
      r.file.title = job.filename;
    }
    setProgress(r.progress, job.progress);
    setAttr(r.progress, "aria-label", t("job.progress"));
    r.jobMeta.update(job);
    this.setThumb(p, job.thumbnail);
  }

  setThumb(p, path) {
    const img = this.refs.thumbImg;
    const usable = path && p.connection === "online";
    const key = usable ? `${p.id}|${path}` : "";
    if (!this.changed("thumb", key)) return;
    this.refs.thumb.classList.toggle("has-image", Boolean(usable));
    if (usable) {
      img.hidden = false;
      img.src = api.thumbnailUrl(p.id, path);
    } else {
      img.hidden = true;
      img.removeAttribute("src");
    }
  }
}

export class Row extends Card {
  constructor(p) {
    super(p.id);
    const r = (this.refs = {
      select: h("input", { type: "checkbox", class: "select", dataset: { select: p.id } }),
      nameLink: h("a", { class: "name-link", href: pageOf(p.id) }),
      model: h("small", { class: "model" }),
      pill: h("span", { class: "pill" }),
      file: h("span", { class: "file" }),
      note: h("small", { class: "note", hidden: true }),
      progress: progressBar(),
      pct: h("span", { class: "pct" }),
      eta: h("span", { class: "eta" }),
      done: h("small", { class: "done" }),
      hotend: h("span", {}),
      bed: h("span", {}),
      location: h("span", {}),
      stale: h("small", { class: "stale", hidden: true }),
      gate: new GateStrip(),
      actions: buildActions(),
    });
    r.name = h("span", { class: "name" }, r.nameLink);
    const td = (cls, ...kids) => h("td", { class: cls }, ...kids);
    this.el = h(
      "tr",
      { dataset: { id: p.id } },
      td("c-select", r.select),
      h("th", { class: "c-name", scope: "row" }, h("span", { class: "name-cell" }, h("span", { class: "dot", "aria-hidden": "true" }), h("span", { class: "name-box" }, r.name, r.model))),
      td("c-status", r.pill, r.stale),
      td("c-job", h("span", { class: "job-line" }, r.file, r.pct), r.progress, r.note, r.gate.el),
      td("c-eta", r.eta, " ", r.done),
      td("c-temp", r.hotend),
      td("c-temp", r.bed),
      td("c-loc", r.location),
      td("c-actions", r.actions),
    );
  }

  update(p, now) {
    const r = this.refs;
    const status = statusOf(p);
    if (this.changed("name", p.name)) setText(r.nameLink, p.name);
    if (this.changed("nameLabel", `${p.name}|${t("aria.select")}`)) {
      setAttr(r.select, "aria-label", t("aria.select", { name: p.name }));
      setAttr(r.progress, "aria-label", t("aria.progress", { name: p.name }));
    }
    setText(r.model, p.model);
    setText(r.location, p.location);
    if (this.changed("status", `${status.group}|${t(status.key)}`)) {
      this.el.dataset.status = status.group;
      setText(r.pill, t(status.key));
    }
    const job = p.job || {};
    const present = hasJob(p);
    setText(r.file, present ? fmt.baseName(job.filename) : "");
    if (present) r.file.title = job.filename;
    setHidden(r.progress, !present);
    if (present) setProgress(r.progress, job.progress);
    setText(r.pct, present ? fmt.percent(job.progress) : "");
    setEta(r.eta, present ? job : {}, present ? "" : "—");
    setText(r.done, present ? doneText(job) : "");
    const note = noteOf(p);
    setText(r.note, note);
    setHidden(r.note, !note);
    setText(r.hotend, `${heaterText(p.extruder)} ${targetText(p.extruder)}`.trim());
    setText(r.bed, `${heaterText(p.bed)} ${targetText(p.bed)}`.trim());
    r.gate.update(p, this.el);
    this.updateStale(p, now);
    updateActions(r.actions, p, this.memo);
  }
}
