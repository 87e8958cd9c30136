// The overview: one card per printer (tiles or table rows), keyed by printer id, updated in
// place and batched into one animation frame. Filters, search, sort and the selection.
import { Row, Tile } from "./cards.js";
import { h, setHidden, setText } from "./dom.js";
import * as fmt from "./format.js";
import { t } from "./i18n.js";
import { onQueueChange } from "./queue_data.js";
import { AWAITING, GROUPS, comparator, facets, gates, matches, orderKey, printers, serverNow, statusOf, subscribe } from "./store.js";
import { forgetCard, observeCard } from "./watch.js";

const VIEW_KEY = "kybercore.view";
const cards = new Map(); // id -> Tile | Row, for the current mode
const orderKeys = new Map();
const dirty = new Set();
export const selection = new Set();
export const view = loadView();

let els = null;
let frame = 0;
let orderDirty = true;
let facetsKey = "";
let countsKey = "";
/** @type {{onAction: (...args: any[]) => void, onSelection: () => void, onDropFiles: (...args: any[]) => void}} */
let hooks = { onAction: () => {}, onSelection: () => {}, onDropFiles: () => {} };

function loadView() {
  const defaults = { mode: "tiles", sort: "name", state: "", tag: "", location: "", q: "" };
  try {
    const saved = JSON.parse(localStorage.getItem(VIEW_KEY) || "{}");
    return { ...defaults, ...saved, q: "" };
  } catch {
    return defaults;
  }
}

function saveView() {
  const { q, ...kept } = view;
  try {
    localStorage.setItem(VIEW_KEY, JSON.stringify(kept));
  } catch {
    // private mode
  }
}

/** Wire the overview to its elements (see fleet.html) and to the action handlers. */
export function initOverview(elements, handlers) {
  els = elements;
  hooks = { ...hooks, ...handlers };
  subscribe(onStoreChange);
  onQueueChange(onGatesChange);
  for (const container of [els.grid, els.tbody]) {
    container.addEventListener("click", onClick);
    container.addEventListener("change", onChange);
    container.addEventListener("dragover", onDragOver);
    container.addEventListener("dragleave", onDragLeave);
    container.addEventListener("drop", onDrop);
  }
  els.search.addEventListener("input", () => setFilter("q", els.search.value.trim()));
  for (const name of ["state", "tag", "location", "sort"]) {
    els[name].value = view[name];
    els[name].addEventListener("change", () => setFilter(name, els[name].value));
  }
  els.counts.addEventListener("click", (event) => {
    const chip = event.target.closest("[data-group]");
    if (!chip) return;
    const group = view.state === chip.dataset.group ? "" : chip.dataset.group;
    els.state.value = group;
    setFilter("state", group);
  });
  els.selectAll.addEventListener("change", () => {
    if (els.selectAll.checked) selectWhere(() => true);
    else clearSelection();
  });
  setInterval(refreshStale, 1000);
  setMode(view.mode);
}

export function setFilter(name, value) {
  view[name] = value;
  saveView();
  orderDirty = true;
  schedule();
}

export function setMode(mode) {
  view.mode = mode === "table" ? "table" : "tiles";
  saveView();
  setHidden(els.grid, view.mode !== "tiles");
  setHidden(els.table, view.mode !== "table");
  for (const button of els.modeButtons) button.setAttribute("aria-pressed", String(button.dataset.mode === view.mode));
  rebuild();
}

/** Throw every card away and build them again (mode or language change). */
export function rebuild() {
  for (const card of cards.values()) drop(card);
  cards.clear();
  for (const id of printers.keys()) dirty.add(id);
  orderDirty = true;
  countsKey = "";
  facetsKey = "";
  schedule();
}

function onStoreChange(change) {
  for (const id of change.removed) {
    if (cards.has(id)) drop(cards.get(id));
    cards.delete(id);
    orderKeys.delete(id);
    if (selection.delete(id)) hooks.onSelection();
  }
  if (change.full) {
    for (const id of [...cards.keys()]) {
      if (!printers.has(id)) {
        drop(cards.get(id));
        cards.delete(id);
      }
    }
    for (const id of [...selection]) if (!printers.has(id)) selection.delete(id);
    hooks.onSelection();
  }
  for (const id of change.changed) {
    dirty.add(id);
    const key = orderKey(printers.get(id));
    if (orderKeys.get(id) !== key) {
      orderKeys.set(id, key);
      orderDirty = true;
    }
  }
  if (change.removed.size) orderDirty = true;
  schedule();
}

/** A plate gate changed: redraw those cards, and the order when the filter shows gates. */
function onGatesChange(change) {
  for (const id of change.gates) if (printers.has(id)) dirty.add(id);
  if (change.gates.size && view.state === AWAITING) orderDirty = true;
  schedule();
}

function schedule() {
  if (!frame) frame = requestAnimationFrame(flush);
}

/** One frame's worth of work: update the dirty cards, then order and counts if needed. */
function flush() {
  frame = 0;
  const started = performance.now();
  const now = serverNow();
  const container = view.mode === "tiles" ? els.grid : els.tbody;
  const dirtyCount = dirty.size;
  for (const id of dirty) {
    const p = printers.get(id);
    if (!p) continue;
    let card = cards.get(id);
    if (!card) {
      card = view.mode === "tiles" ? new Tile(p) : new Row(p);
      card.refs.select.checked = selection.has(id);
      cards.set(id, card);
      container.append(card.el);
      observeCard(card.el); // what is on screen gets full views, the rest summaries
      orderDirty = true;
    }
    card.update(p, now);
  }
  dirty.clear();
  if (orderDirty) {
    orderDirty = false;
    reorder(container);
    updateFacets();
  }
  updateCounts();
  // Visible in the browser's performance tools (and read by the scale test).
  performance.measure("kybercore:render", { start: started, detail: dirtyCount });
}

function drop(card) {
  forgetCard(card.el);
  card.el.remove();
}

function reorder(container) {
  const shown = [...printers.values()].filter((p) => matches(p, view)).sort(comparator(view.sort));
  const visible = new Set(shown.map((p) => p.id));
  for (const [id, card] of cards) setHidden(card.el, !visible.has(id));
  let cursor = container.firstElementChild;
  for (const p of shown) {
    const el = cards.get(p.id)?.el;
    if (!el) continue;
    if (el === cursor) cursor = cursor.nextElementSibling;
    else container.insertBefore(el, cursor);
  }
  const total = printers.size;
  setHidden(els.empty, shown.length > 0);
  setText(els.empty, total ? t("overview.no_match") : t("overview.no_printers"));
  setText(els.shown, shown.length === total ? t("overview.count", { n: total }) : t("overview.count_of", { n: shown.length, total }));
  syncSelectAll();
}

function updateFacets() {
  const { tags, locations } = facets();
  const key = `${tags.join("\n")}|${locations.join("\n")}|${t("filter.any_tag")}`;
  if (key === facetsKey) return;
  facetsKey = key;
  fillSelect(els.tag, tags, t("filter.any_tag"), view.tag);
  fillSelect(els.location, locations, t("filter.any_location"), view.location);
}

function fillSelect(select, values, anyLabel, current) {
  const options = [h("option", { value: "", text: anyLabel }), ...values.map((v) => h("option", { value: v, text: v }))];
  if (current && !values.includes(current)) options.push(h("option", { value: current, text: current }));
  select.replaceChildren(...options);
  select.value = current;
}

function updateCounts() {
  const counts = Object.fromEntries(GROUPS.map((g) => [g, 0]));
  for (const p of printers.values()) counts[statusOf(p).group] += 1;
  // Plates to clear, at a glance: a printer in it is also counted by its status.
  counts[AWAITING] = [...gates.entries()].filter(([id, gate]) => gate.state === AWAITING && printers.has(id)).length;
  const shown = [...GROUPS, AWAITING];
  const next = nextToFinish();
  const nextKey = next ? `${next.name}|${Math.round(next.job.eta_at / 60)}` : "";
  const key = `${shown.map((g) => counts[g]).join(",")}|${view.state}|${t("group.printing")}|${nextKey}`;
  if (key === countsKey) return;
  countsKey = key;
  els.counts.replaceChildren(
    ...shown.map((group) =>
      h(
        "button",
        { type: "button", class: "count-chip", dataset: { group }, "aria-pressed": String(view.state === group), title: t("filter.only", { state: t(`group.${group}`) }) },
        h("span", { class: "dot", "aria-hidden": "true" }),
        h("strong", { text: String(counts[group]) }),
        h("span", { text: t(`group.${group}`, { n: counts[group] }) }),
      ),
    ),
    // replaceChildren() writes a null as the text "null": leave the slot out instead.
    ...(next ? [h("span", { class: "next-finish", text: t("summary.next", { name: next.name, when: fmt.doneText(next.job, serverNow()) }) })] : []),
  );
}

/** The printing printer whose print ends first (by its clock time), or null. */
function nextToFinish() {
  let next = null;
  for (const p of printers.values()) {
    if (p.job?.state !== "printing" || typeof p.job.eta_at !== "number") continue;
    if (!next || p.job.eta_at < next.job.eta_at) next = p;
  }
  return next;
}

function refreshStale() {
  const now = serverNow();
  for (const [id, card] of cards) {
    const p = printers.get(id);
    if (p) card.updateStale(p, now);
  }
}

// -- events (delegated: one listener per container, whatever the fleet size) -----------------

function onClick(event) {
  const button = event.target.closest("button[data-action]");
  if (!button || button.disabled) return;
  const id = button.closest("[data-id]")?.dataset.id;
  if (id && printers.has(id)) hooks.onAction(id, button.dataset.action, button);
}

function onChange(event) {
  const box = event.target.closest("input[data-select]");
  if (!box) return;
  if (box.checked) selection.add(box.dataset.select);
  else selection.delete(box.dataset.select);
  syncSelectAll();
  hooks.onSelection();
}

function cardFromEvent(event) {
  return event.target.closest?.("[data-id]");
}

function onDragOver(event) {
  const card = cardFromEvent(event);
  if (!card || !event.dataTransfer?.types.includes("Files")) return;
  event.preventDefault();
  card.classList.add("drop-target");
}

function onDragLeave(event) {
  const card = cardFromEvent(event);
  if (card && !card.contains(event.relatedTarget)) card.classList.remove("drop-target");
}

function onDrop(event) {
  const card = cardFromEvent(event);
  if (!card || !event.dataTransfer?.files.length) return;
  event.preventDefault();
  card.classList.remove("drop-target");
  hooks.onDropFiles(card.dataset.id, [...event.dataTransfer.files]);
}

// -- selection -------------------------------------------------------------------------------

/** Select the shown printers for which `test(p)` holds (e.g. all idle ones). */
export function selectWhere(test) {
  selection.clear();
  for (const p of printers.values()) if (matches(p, view) && test(p)) selection.add(p.id);
  syncCheckboxes();
}

/** Select a status group; "ready" leaves out printers whose plate awaits a clear. */
export function selectGroup(group) {
  selectWhere((p) => statusOf(p).group === group && !(group === "ready" && gates.get(p.id)?.state === AWAITING));
}

export function clearSelection() {
  selection.clear();
  syncCheckboxes();
}

function syncCheckboxes() {
  for (const [id, card] of cards) card.refs.select.checked = selection.has(id);
  syncSelectAll();
  hooks.onSelection();
}

function syncSelectAll() {
  const shown = [...printers.values()].filter((p) => matches(p, view));
  const picked = shown.filter((p) => selection.has(p.id)).length;
  els.selectAll.checked = shown.length > 0 && picked === shown.length;
  els.selectAll.indeterminate = picked > 0 && picked < shown.length;
}
