// Which printers this page shows in full: the tiles or rows on screen (and just beyond), the
// printer in the drawer, the printer page's printer. The server then sends full views of
// those only, and of the others the slim summary the filters, sorts, counts and
// notifications need: a browser showing 24 tiles of 2,000 printers no longer receives, parses
// and merges 2,000 printers' temperatures four times a second.
import { watchView } from "./live.js";

const SETTLE_MS = 150; // scrolling through hundreds of tiles asks once, when it stops

/** @type {Map<string, Set<string>>} what each part of the page shows */
const shown = new Map();
let timer = undefined;
/** @type {IntersectionObserver | null} */
let observer = null;
const onScreen = new Set();

/**
 * Say which printers `source` shows now (replacing what it said before).
 * @param {string} source
 * @param {Iterable<string>} ids
 */
export function show(source, ids) {
  shown.set(source, new Set(ids));
  clearTimeout(timer);
  timer = setTimeout(send, SETTLE_MS);
}

/**
 * Settle the view now rather than after the delay: called before the first connection, so a
 * page opened on one printer (#printer/<id>) names it and gets its snapshot, not the fleet's
 * in full.
 */
export function showNow() {
  clearTimeout(timer);
  send();
}

function send() {
  // Until the cards have said what is on screen, every printer stays in full: asking for
  // the drawer's and the page's nothing first would turn the tiles on screen into summaries
  // for a moment, and back.
  if (!shown.has("cards") && ![...shown.values()].some((ids) => ids.size)) return;
  const all = new Set();
  for (const ids of shown.values()) for (const id of ids) all.add(id);
  watchView([...all].sort());
}

/**
 * Follow a card (tile or table row, with data-id) on screen: hidden by a filter, on another
 * page or scrolled away, it is not shown. A margin around the viewport fetches the cards
 * about to scroll in before they do.
 * @param {HTMLElement} el
 */
export function observeCard(el) {
  observer ||= new IntersectionObserver(onIntersect, { rootMargin: "400px 0px" });
  observer.observe(el);
}

/** @param {HTMLElement} el */
export function forgetCard(el) {
  observer?.unobserve(el);
  if (onScreen.delete(el.dataset.id)) show("cards", onScreen);
}

/** @param {IntersectionObserverEntry[]} entries */
function onIntersect(entries) {
  for (const entry of entries) {
    const id = /** @type {HTMLElement} */ (entry.target).dataset.id;
    if (entry.isIntersecting) onScreen.add(id);
    else onScreen.delete(id);
  }
  show("cards", onScreen);
}
