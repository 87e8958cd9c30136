// The camera wall (#cameras): a snapshot of every printer that has a webcam, with its name,
// state and progress, each linking to the printer's page. Snapshots are refreshed one tile
// at a time, round robin: one request in flight however many printers there are (a stream
// per tile would hold a connection each, and browsers allow about six per host). Nothing is
// fetched while the page is hidden.
import { api } from "./api.js";
import { pageOf } from "./cards.js";
import { h, setText } from "./dom.js";
import * as fmt from "./format.js";
import { t } from "./i18n.js";
import { printers, statusOf, subscribe } from "./store.js";
import { transformOf } from "./webcam_view.js";

export const CAMERAS_HASH = "#cameras";
// The pause after each snapshot: a wall of 50 printers shows each about every 30 s.
const GAP_MS = 300;

let root = null;
let shown = false;
let tiles = new Map(); // printer id -> {cam, img, pill, progress, el}
let order = [];
let next = 0;
let timer = null;
let running = false; // a snapshot is being fetched
let listed = null; // a promise while the webcam lists load

/** Show or hide the wall for the page the router chose. */
export function showCamerasPage(page) {
  root ||= init(document.getElementById("cameras-view"));
  const show = page === "cameras";
  root.hidden = !show;
  if (show === shown) return;
  shown = show;
  if (show) load();
  else stop();
}

function init(el) {
  subscribe((change) => {
    if (!shown) return;
    for (const id of change.changed) updateTile(id);
    if (change.full || change.removed.size) load(); // printers came or went
  });
  document.addEventListener("visibilitychange", () => {
    if (shown && !document.hidden) pump();
  });
  return el;
}

/** Ask every online printer for its webcams (three at a time), then build the wall. */
async function load() {
  if (listed) return listed;
  listed = (async () => {
    const ids = [...printers.keys()].filter((id) => printers.get(id).connection === "online");
    const cams = new Map();
    let at = 0;
    const worker = async () => {
      while (at < ids.length) {
        const id = ids[at++];
        try {
          const list = await api.webcams(id);
          if (list.length) cams.set(id, list[0]);
        } catch {
          // A printer that went away meanwhile simply has no tile.
        }
      }
    };
    await Promise.all([worker(), worker(), worker()]);
    if (shown) build(cams);
  })();
  try {
    await listed;
  } finally {
    listed = null;
  }
}

function build(cams) {
  stop();
  tiles = new Map();
  const grid = h("ul", { class: "cam-grid" });
  const ids = [...cams.keys()].sort((a, b) => (printers.get(a)?.name || a).localeCompare(printers.get(b)?.name || b));
  for (const id of ids) {
    const cam = cams.get(id);
    const name = printers.get(id)?.name || id;
    const img = h("img", { class: "cam-img", alt: t("cam.alt", { name, cam: cam.name }), decoding: "async" });
    img.style.transform = transformOf(cam);
    const pill = h("span", { class: "pill" });
    const progress = h("span", { class: "cam-progress" });
    const el = h(
      "li",
      { class: "cam-tile", dataset: { id } },
      h("a", { class: "cam-link", href: pageOf(id), "aria-label": t("pp.open_page", { name }) }, h("div", { class: "cam-frame" }, img)),
      h("div", { class: "cam-caption" }, h("a", { class: "name-link", href: pageOf(id), text: name }), pill, progress),
    );
    tiles.set(id, { cam, img, pill, progress, el, url: null });
    grid.append(el);
    updateTile(id);
  }
  order = ids;
  next = 0;
  const head = h("header", { class: "ledger-head" }, h("h2", { id: "cameras-title", text: t("cam.title") }), h("p", { class: "muted", text: t("cam.summary", { n: ids.length }) }));
  root.replaceChildren(head, ids.length ? grid : h("p", { class: "empty", text: t("cam.none") }));
  pump();
}

function updateTile(id) {
  const tile = tiles.get(id);
  const p = printers.get(id);
  if (!tile || !p) return;
  const status = statusOf(p);
  tile.el.dataset.status = status.group;
  setText(tile.pill, t(status.key));
  const busy = status.group === "printing" || status.group === "paused";
  setText(tile.progress, busy ? fmt.percent(p.job?.progress) : "");
}

/** Fetch the next tile's snapshot, then the one after, while the wall is on screen. */
async function pump() {
  if (running || !shown || document.hidden || !order.length) return;
  running = true;
  const id = order[next % order.length];
  next += 1;
  const tile = tiles.get(id);
  try {
    const blob = await fetch(tile.cam.snapshot_url, { cache: "no-store" }).then((r) => (r.ok ? r.blob() : null));
    if (blob && tiles.get(id) === tile) {
      const url = URL.createObjectURL(blob);
      tile.img.src = url;
      if (tile.url) URL.revokeObjectURL(tile.url);
      tile.url = url;
      tile.el.classList.remove("cam-failed");
    } else tile.el.classList.add("cam-failed");
  } catch {
    tile.el.classList.add("cam-failed"); // the next round tries again
  } finally {
    running = false;
  }
  clearTimeout(timer);
  timer = setTimeout(pump, GAP_MS);
}

function stop() {
  clearTimeout(timer);
  timer = null;
  for (const tile of tiles.values()) if (tile.url) URL.revokeObjectURL(tile.url);
}
