// Webcams in the browser, always through KyberCore's proxy (/api/printers/{id}/webcams):
// the printer page's full stream, and the camera wall's snapshots. A live MJPEG stream
// holds a connection for as long as it shows, and browsers allow about six per host, so
// only the printer page streams; every other view refreshes snapshots.
import { api } from "./api.js";
import { h, setText } from "./dom.js";
import { t } from "./i18n.js";
import { printers } from "./store.js";

// The stream failed (the camera serves snapshots only, or too many streams are open):
// a snapshot this often instead.
const FALLBACK_MS = 2000;

/** @typedef {{section: HTMLElement, img: HTMLImageElement | null, timer: number | undefined}} Shown */
/** @type {Shown | null} */
let current = null;

/** Show printer `id`'s first webcam, streaming, in `section` (hidden when it has none). */
export async function renderWebcam(section, id) {
  stopWebcam();
  /** @type {Shown} */
  const mine = { section, img: null, timer: undefined };
  current = mine;
  let cams = [];
  try {
    cams = await api.webcams(id);
  } catch {
    cams = []; // offline printer: no camera to show, the page says why elsewhere
  }
  if (current !== mine || !cams.length) return;
  const cam = cams[0];
  const name = printers.get(id)?.name || id;
  const img = h("img", { class: "webcam-img", alt: t("cam.alt", { name, cam: cam.name }), src: cam.stream_url });
  img.style.transform = transformOf(cam); // CSSOM: the CSP refuses style attributes
  const note = h("p", { class: "webcam-note", role: "status" });
  img.addEventListener("error", () => {
    if (current !== mine || mine.timer) return;
    setText(note, t("cam.snapshots"));
    const refresh = () => {
      img.src = `${cam.snapshot_url}?t=${Date.now()}`;
    };
    mine.timer = setInterval(refresh, FALLBACK_MS);
    refresh();
  });
  mine.img = img;
  section.append(img, note);
  section.hidden = false;
}

/** Stop streaming (leaving the page closes the camera's connection at once). */
export function stopWebcam() {
  if (!current) return;
  clearInterval(current.timer);
  if (current.img) current.img.src = ""; // an <img> keeps its stream open until then
  current.img?.remove();
  current.section.querySelector(".webcam-note")?.remove();
  current.section.hidden = true;
  current = null;
}

/** Moonraker's flip and rotation settings as a CSS transform ("" for none). */
export function transformOf(cam) {
  const parts = [];
  if (cam.rotation) parts.push(`rotate(${cam.rotation}deg)`);
  if (cam.flip_horizontal) parts.push("scaleX(-1)");
  if (cam.flip_vertical) parts.push("scaleY(-1)");
  return parts.join(" ");
}
