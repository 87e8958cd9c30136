// The Queue view: jobs in dispatch order with their copies (done / in progress / left),
// priority, state and why they wait; drag (or the arrow buttons) to reorder, cancel with a
// confirmation, pause and resume the whole queue. One row per job, kept by id and updated
// in place. Live through queue_data.js.
import { ApiError, api } from "./api.js";
import { confirmDialog, toast } from "./dialogs.js";
import { h, icon, setAttr, setHidden, setText } from "./dom.js";
import { sinceText } from "./gates.js";
import { messageOf, reasonText, t } from "./i18n.js";
import { jobDialog } from "./job_form.js";
import { onQueueChange, queue, refreshQueue, showFinished } from "./queue_data.js";
import { can } from "./session.js";
import { printers } from "./store.js";

const ACTIVE = new Set(["queued", "blocked"]);
const rows = new Map(); // job id -> JobRow
const expanded = new Set(); // job ids whose details are open
let els = null;
let dragged = null;

/** Wire the view to its elements (see fleet.html). */
export function initQueue(elements) {
  els = elements;
  els.add.addEventListener("click", () => jobDialog());
  els.pause.addEventListener("click", togglePause);
  els.finished.addEventListener("change", () => showFinished(els.finished.checked));
  els.list.addEventListener("click", onClick);
  els.list.addEventListener("change", onPriority);
  els.list.addEventListener("dragstart", onDragStart);
  els.list.addEventListener("dragover", onDragOver);
  els.list.addEventListener("dragleave", () => clearDropMarks());
  els.list.addEventListener("drop", onDrop);
  els.list.addEventListener("dragend", () => {
    dragged = null;
    clearDropMarks();
    for (const row of els.list.querySelectorAll(".dragging")) row.classList.remove("dragging");
  });
  onQueueChange(render);
}

/** Draw everything again (language or role changed). */
export function relabelQueue() {
  for (const row of rows.values()) row.key = null;
  render();
}

const nameOf = (job) => job.file.name;
const printerName = (id) => printers.get(id)?.name || id;

function render() {
  const state = queue.state;
  const operator = can("operator");
  setText(els.pause.lastElementChild, t(state?.paused ? "queue.resume" : "queue.pause"));
  els.pause.disabled = !operator || !state;
  els.add.disabled = !operator;
  setHidden(els.pausedNote, !state?.paused);
  setText(els.summary, state ? summaryOf(state) : "");
  setText(els.count, state && state.queued ? String(state.queued) : "");
  const seen = new Set();
  const movable = queue.jobs.filter((j) => ACTIVE.has(j.state)).map((j) => j.id);
  let cursor = els.list.firstElementChild;
  for (const job of queue.jobs) {
    seen.add(job.id);
    let row = rows.get(job.id);
    if (!row) {
      row = new JobRow(job.id);
      rows.set(job.id, row);
    }
    row.update(job, operator, { first: movable[0] === job.id, last: movable.at(-1) === job.id });
    if (row.el === cursor) cursor = cursor.nextElementSibling;
    else els.list.insertBefore(row.el, cursor);
    if (expanded.has(job.id)) row.loadDetails(job);
  }
  for (const [id, row] of rows) {
    if (!seen.has(id)) {
      row.el.remove();
      rows.delete(id);
      expanded.delete(id);
    }
  }
  const empty = queue.loaded && !queue.jobs.length;
  setHidden(els.empty, !empty && queue.loaded && !queue.error);
  setText(els.empty, queue.error ? messageOf(queue.error) : queue.loaded ? t("queue.empty") : t("queue.loading"));
}

/** "3 jobs · 1 copy to start · …", each count in its own singular or plural. */
function summaryOf(state) {
  const counts = { jobs: state.queued, left: state.copies_left, printing: state.copies_printing, clear: state.awaiting_clear.length };
  return Object.entries(counts).map(([part, n]) => t(`queue.summary.${part}`, { n })).join(" · ");
}

/** What the pill says and which color it takes. */
function stateOf(job) {
  if (job.state !== "queued") return { key: job.state, status: { blocked: "error", done: "ready", cancelled: "offline" }[job.state] };
  // A copy printed but not cleared is the operator's turn, not the printer's.
  if (job.in_flight > 0 && job.awaiting_clear === job.in_flight) return { key: "to_clear", status: "awaiting_clear" };
  if (job.in_flight > 0) return { key: "printing", status: "printing" };
  return { key: queue.state?.paused ? "paused" : "waiting", status: "paused" };
}

function needs(job) {
  const r = job.requirements;
  return [
    r.material,
    r.nozzle ? `${r.nozzle} mm` : null,
    r.model,
    ...r.tags.map((tag) => `#${tag}`),
    r.printer ? t("queue.pinned", { printer: printerName(r.printer) }) : null,
    job.not_before ? t("queue.not_before", { time: sinceText(job.not_before) }) : null,
  ].filter(Boolean);
}

class JobRow {
  constructor(id) {
    this.id = id;
    this.key = null;
    const r = (this.refs = {
      grip: h("span", { class: "grip", title: t("queue.drag") }, icon("grip")),
      name: h("p", { class: "job-name" }),
      needs: h("p", { class: "job-needs" }),
      note: h("p", { class: "job-note", hidden: true }),
      bar: h("div", { class: "copies-bar", "aria-hidden": "true" }, h("span", { class: "seg done" }), h("span", { class: "seg flight" }), h("span", { class: "seg clear" })),
      copies: h("p", { class: "copies-text" }),
      priority: h("input", { type: "number", class: "priority", min: "-1000", max: "1000", step: "1", dataset: { jobAction: "priority" } }),
      pill: h("span", { class: "pill" }),
      why: h("button", { type: "button", class: "btn small", dataset: { jobAction: "why" }, "aria-expanded": "false" }),
      up: h("button", { type: "button", class: "icon-btn", dataset: { jobAction: "up" } }, icon("up")),
      down: h("button", { type: "button", class: "icon-btn", dataset: { jobAction: "down" } }, icon("down")),
      requeue: h("button", { type: "button", class: "btn small", dataset: { jobAction: "requeue" }, hidden: true }),
      cancel: h("button", { type: "button", class: "icon-btn danger", dataset: { jobAction: "cancel" } }, icon("remove")),
      details: h("div", { class: "job-details", hidden: true, id: `job-${id}-details` }),
    });
    setAttr(r.why, "aria-controls", r.details.id);
    this.el = h(
      "li",
      { class: "job-row", dataset: { jobId: String(id) } },
      r.grip,
      h("div", { class: "job-main" }, r.name, r.needs, r.note),
      h("div", { class: "job-copies" }, r.bar, r.copies),
      h("label", { class: "job-priority" }, h("span", { class: "caption" }), r.priority),
      r.pill,
      h("div", { class: "job-actions" }, r.why, r.up, r.down, r.requeue, r.cancel),
      r.details,
    );
  }

  /** `place`: {first, last} among the jobs that can move. */
  update(job, operator, place) {
    this.job = job;
    const key = JSON.stringify([job, operator, place, queue.state?.paused, t("queue.why")]);
    if (key === this.key) return;
    this.key = key;
    const r = this.refs;
    const name = nameOf(job);
    const active = ACTIVE.has(job.state);
    const state = stateOf(job);
    this.el.dataset.state = job.state;
    this.el.draggable = active && operator;
    setHidden(r.grip, !this.el.draggable);
    r.grip.title = t("queue.drag");
    setText(r.name, name);
    r.name.title = name;
    r.needs.replaceChildren(...(needs(job).length ? needs(job) : [t("queue.needs_any")]).map((text) => h("span", { class: "tag", text })));
    const note = job.reason || (job.failures ? t("queue.failures", { n: job.failures }) : "");
    setText(r.note, note);
    setHidden(r.note, !note);
    const share = (n) => `${(100 * n) / job.quantity}%`;
    /** @type {HTMLElement} */ (r.bar.children[0]).style.width = share(job.done);
    const printing = job.in_flight - job.awaiting_clear;
    /** @type {HTMLElement} */ (r.bar.children[1]).style.width = share(printing);
    /** @type {HTMLElement} */ (r.bar.children[2]).style.width = share(job.awaiting_clear);
    const copies = { done: job.done, printing, clear: job.awaiting_clear, left: job.left, n: job.quantity };
    setText(r.copies, t(job.awaiting_clear ? "queue.copies_clear" : "queue.copies", copies));
    if (document.activeElement !== r.priority) r.priority.value = String(job.priority);
    r.priority.disabled = !operator || !active;
    setText(r.priority.previousElementSibling, t("jobform.priority"));
    setAttr(r.priority, "aria-label", t("queue.priority_of", { name }));
    setAttr(r.priority, "title", t("queue.priority"));
    r.pill.dataset.status = state.status;
    setText(r.pill, t(`queue.state.${state.key}`));
    setText(r.why, t(job.state === "queued" ? "queue.why" : "queue.details"));
    setHidden(r.requeue, job.state !== "blocked");
    setText(r.requeue, t("queue.requeue"));
    /** @type {[HTMLButtonElement, string][]} */
    const moves = [[r.up, "queue.move_up"], [r.down, "queue.move_down"], [r.cancel, "queue.cancel_named"]];
    for (const [button, label] of moves) {
      setAttr(button, "aria-label", t(label, { name }));
      setAttr(button, "title", t(label, { name }));
      setHidden(button, !active);
      button.disabled = !operator;
    }
    r.up.disabled ||= place.first;
    r.down.disabled ||= place.last;
    r.requeue.disabled = !operator;
  }

  /** Show the live copies and why the job waits (read now; again on every change). */
  async loadDetails(job) {
    const r = this.refs;
    r.why.setAttribute("aria-expanded", "true");
    setHidden(r.details, false);
    if (!r.details.firstChild) r.details.append(h("p", { class: "muted", text: t("queue.why_loading") }));
    let attempts;
    let why;
    try {
      [attempts, why] = await Promise.all([api.attempts(job.id), job.state === "queued" ? api.why(job.id) : []]);
    } catch (error) {
      r.details.replaceChildren(h("p", { class: "form-error", text: messageOf(error) }));
      return;
    }
    if (!expanded.has(job.id)) return;
    const copies = attempts.filter((a) => !a.verdict && !["failed", "cancelled", "failed_to_start"].includes(a.state));
    const lines = [
      ...copies.map((a) => h("li", { class: "copy-line", text: t("queue.copy_line", { copy: a.copy, state: t(`attempt.${a.state}`), printer: printerName(a.printer) }) })),
      ...why.map((line) => h("li", { class: "reason", dataset: { code: line.code }, text: `${line.subject === "queue" ? "" : `${printerName(line.subject)}: `}${reasonText(line)}` })),
    ];
    if (job.state === "queued" && !why.length) lines.push(h("li", { class: "muted", text: t("queue.why_none") }));
    r.details.replaceChildren(h("ul", { class: "reason-list" }, lines));
  }

  collapse() {
    this.refs.why.setAttribute("aria-expanded", "false");
    setHidden(this.refs.details, true);
    this.refs.details.replaceChildren();
  }
}

// -- actions ----------------------------------------------------------------------------------

function rowOf(event) {
  const el = event.target.closest?.("[data-job-id]");
  return el ? rows.get(Number(el.dataset.jobId)) : null;
}

async function onClick(event) {
  const button = event.target.closest("button[data-job-action]");
  const row = button && rowOf(event);
  if (!row || button.disabled) return;
  const job = row.job;
  const action = button.dataset.jobAction;
  if (action === "why") {
    if (expanded.delete(job.id)) row.collapse();
    else {
      expanded.add(job.id);
      row.loadDetails(job);
    }
    return;
  }
  button.classList.add("busy");
  try {
    if (action === "cancel") await cancelJob(job);
    else if (action === "requeue") await run(() => api.requeueJob(job.id), t("done.requeue", { name: nameOf(job) }));
    else await move(job, action === "up" ? -1 : 2);
  } finally {
    button.classList.remove("busy");
  }
}

/** Send a change; a toast for its outcome; the queue is read again. */
async function run(send, doneMessage) {
  try {
    await send();
    if (doneMessage) toast({ kind: "ok", message: doneMessage });
  } catch (error) {
    toast({ kind: "error", title: t("queue.title"), message: messageOf(error) });
  }
  refreshQueue(0);
}

/** Move a job by `offset` rows among the active ones: -1 up; 2 down (before the one after next). */
function move(job, offset) {
  const active = queue.jobs.filter((j) => ACTIVE.has(j.state));
  const index = active.findIndex((j) => j.id === job.id) + offset;
  if (index < 0 || (offset > 0 && index - 1 >= active.length)) return null;
  return run(() => api.moveJob(job.id, active[index]?.id ?? null));
}

async function cancelJob(job) {
  const name = nameOf(job);
  const ok = await confirmDialog({ title: t("queue.cancel_title", { name }), message: t("queue.cancel_body"), confirmLabel: t("queue.cancel"), danger: true });
  if (!ok) return;
  try {
    await api.cancelJob(job.id);
  } catch (error) {
    if (!(error instanceof ApiError) || error.code !== "confirmation_required") {
      toast({ kind: "error", title: t("queue.cancel"), message: messageOf(error) });
      return;
    }
    const prints = await confirmDialog({
      title: t("queue.cancel_prints_title", { name }),
      message: t("queue.cancel_prints_body"),
      details: error.reasons.map((r) => ({ level: "warn", text: reasonText(r) })),
      confirmLabel: t("queue.cancel_prints"),
      danger: true,
    });
    if (!prints) return;
    return run(() => api.cancelJob(job.id, true), t("done.cancel_job", { name }));
  }
  toast({ kind: "ok", message: t("done.cancel_job", { name }) });
  refreshQueue(0);
}

function onPriority(event) {
  const input = event.target.closest("input[data-job-action=priority]");
  const row = input && rowOf(event);
  const value = Number(input?.value);
  if (!row || !Number.isInteger(value) || value === row.job.priority) return;
  run(() => api.editJob(row.job.id, { priority: value }));
}

async function togglePause() {
  const paused = !queue.state?.paused;
  await run(() => api.pauseQueue(paused), t(paused ? "done.queue_paused" : "done.queue_resumed"));
}

// -- drag to reorder ----------------------------------------------------------------------

function onDragStart(event) {
  const row = rowOf(event);
  if (!row || !row.el.draggable) return;
  dragged = row.job.id;
  row.el.classList.add("dragging");
  event.dataTransfer.effectAllowed = "move";
  event.dataTransfer.setData("text/plain", String(dragged));
}

/** The job the dragged one would be put before, for a pointer over `row` (null: last). */
function dropTarget(event, row) {
  const box = row.el.getBoundingClientRect();
  const upper = event.clientY < box.top + box.height / 2;
  const active = queue.jobs.filter((j) => ACTIVE.has(j.state));
  const index = active.findIndex((j) => j.id === row.job.id);
  return { upper, before: upper ? row.job.id : (active[index + 1]?.id ?? null) };
}

function onDragOver(event) {
  const row = rowOf(event);
  if (dragged === null || !row || !ACTIVE.has(row.job.state)) return;
  event.preventDefault();
  event.dataTransfer.dropEffect = "move";
  const { upper } = dropTarget(event, row);
  clearDropMarks();
  row.el.classList.add(upper ? "drop-before" : "drop-after");
}

function onDrop(event) {
  const row = rowOf(event);
  if (dragged === null || !row || !ACTIVE.has(row.job.state)) return;
  event.preventDefault();
  const { before } = dropTarget(event, row);
  const id = dragged;
  dragged = null;
  clearDropMarks();
  if (before !== id) run(() => api.moveJob(id, before));
}

function clearDropMarks() {
  for (const el of els.list.querySelectorAll(".drop-before, .drop-after")) el.classList.remove("drop-before", "drop-after");
}
