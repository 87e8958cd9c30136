// The printer drawer's temperature graph: hotend and bed, reading and target, over the
// last 30 minutes. The history comes once from the backend's ring buffer
// (GET /api/printers/{id}/temperatures); from then on each second adds the live values the
// page already receives over /ws, so an open graph costs the printer nothing.
import { api } from "./api.js";
import { timeChart } from "./charts.js";
import { t } from "./i18n.js";
import { printers } from "./store.js";

const WINDOW = 30 * 60;
const HEATERS = [
  ["extruder", "extruder", "--heat"],
  ["heater_bed", "bed", "--accent"],
];

/**
 * The graph on show: its printer, box, columns (times, then reading and target per heater),
 * chart and the timer that adds a second.
 * @typedef {{id: string, box: HTMLElement, data: Columns, graph: Chart | null,
 *   timer: number | undefined}} Shown
 * @typedef {import("./charts.js").Chart} Chart
 * @typedef {[number[], ...(number | null)[][]]} Columns times (epoch s), then the values
 */

/** @type {Shown | null} */
let shown = null;

/**
 * Draw printer `id`'s graph into `box` (replacing any other).
 * @param {HTMLElement} box
 * @param {string} id
 */
export async function showTemperatures(box, id) {
  hideTemperatures();
  /** @type {Shown} */
  const state = { id, box, data: [[]], graph: null, timer: undefined };
  shown = state;
  box.hidden = false;
  let history = { series: {} };
  try {
    history = await api.temperatures(id, 30);
  } catch {
    // Offline backend or printer gone: the live values still draw from now on.
  }
  if (shown !== state) return;
  state.data = merge(history.series);
  const series = HEATERS.flatMap(([, view, stroke]) => [
    { label: t(`temps.${view}`), stroke },
    { label: t(`temps.${view}_target`), stroke, dash: true },
  ]);
  const graph = await timeChart(box, { series, data: state.data, height: 170, unit: "°", window: WINDOW, timeLabel: t("temps.time") });
  state.graph = graph;
  if (shown !== state) {
    graph.destroy();
    return;
  }
  box.setAttribute("role", "img");
  describe(state);
  state.timer = setInterval(() => tick(state), 1000);
}

export function hideTemperatures() {
  if (!shown) return;
  clearInterval(shown.timer);
  shown.graph?.destroy();
  shown.box.replaceChildren();
  shown.box.hidden = true;
  shown = null;
}

/** Redraw the labels in the current language. */
export function relabelTemperatures() {
  if (shown?.graph) showTemperatures(shown.box, shown.id);
}

/**
 * The backend's per-heater series on one time axis. A heater sends only changes, so a
 * value holds until its next sample: carry it forward (a null, a break, carries too).
 * @param {Record<string, {t: number[], temperature: (number | null)[], target: (number | null)[]}>} series
 * @returns {Columns}
 */
function merge(series) {
  const times = [...new Set(HEATERS.flatMap(([name]) => series[name]?.t || []))].sort((a, b) => a - b);
  /** @type {Columns} */
  const columns = [times];
  for (const [name] of HEATERS) {
    const s = series[name] || { t: [], temperature: [], target: [] };
    for (const field of ["temperature", "target"]) {
      const column = [];
      let next = 0;
      let value = null;
      for (const time of times) {
        while (next < s.t.length && s.t[next] <= time) value = s[field][next++];
        column.push(value);
      }
      columns.push(column);
    }
  }
  return columns;
}

/** @param {Shown} state */
function tick(state) {
  const p = printers.get(state.id);
  if (!p || !state.graph) return;
  const now = Date.now() / 1000;
  const live = p.connection === "online";
  const values = HEATERS.flatMap(([, view]) => {
    const heater = p[view] || {};
    return live ? [heater.temperature ?? null, heater.target ?? null] : [null, null];
  });
  const data = state.data;
  data[0].push(now);
  values.forEach((v, i) => data[i + 1].push(v));
  let old = 0;
  while (old < data[0].length && data[0][old] < now - WINDOW) old += 1;
  if (old) for (const column of data) column.splice(0, old);
  state.graph.chart.setData(data);
  describe(state);
}

/** What the graph shows, in words (for screen readers and tests). */
function describe(state) {
  const data = state.data;
  const last = data[0].length - 1;
  const parts = HEATERS.map(([, view], i) => {
    const temp = last >= 0 ? data[1 + 2 * i][last] : null;
    const target = last >= 0 ? data[2 + 2 * i][last] : null;
    const value = typeof temp === "number" ? `${temp.toFixed(1)}°` : "—";
    return `${t(`temps.${view}`)} ${value} (${t("temps.target")} ${typeof target === "number" ? `${target.toFixed(0)}°` : "—"})`;
  });
  state.box.setAttribute("aria-label", `${t("temps.title")}: ${parts.join(", ")}`);
  state.box.dataset.points = String(data[0].length);
}
