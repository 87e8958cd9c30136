// Graphs with uPlot, vendored in vendor/ (no CDN: farms run on closed LANs) and loaded the
// first time a view draws one. Found from this module's own address, so it comes from the
// same versioned /static/v-<token>/ as the page. Colours come from the theme's CSS
// variables, so a graph follows light and dark like the rest of the page; each chart also
// gets a text summary (aria-label) for screen readers.

/** @type {Promise<UPlotStatic> | null} */
let loading = null;

/**
 * uPlot, once its script and stylesheet are loaded.
 * @returns {Promise<UPlotStatic>}
 */
export function loadCharts() {
  if (window.uPlot) return Promise.resolve(window.uPlot);
  if (!loading) {
    loading = new Promise((resolve, reject) => {
      const css = document.createElement("link");
      css.rel = "stylesheet";
      css.href = new URL("vendor/uPlot.min.css", import.meta.url).href;
      document.head.append(css);
      const script = document.createElement("script");
      script.src = new URL("vendor/uPlot.iife.min.js", import.meta.url).href;
      script.addEventListener("load", () => resolve(/** @type {UPlotStatic} */ (window.uPlot)));
      script.addEventListener("error", () => {
        loading = null;
        reject(new Error("uPlot did not load"));
      });
      document.head.append(script);
    });
  }
  return loading;
}

/** A theme colour by CSS variable name ("--heat"). */
export function color(name) {
  return getComputedStyle(document.documentElement).getPropertyValue(name).trim() || "#888";
}

function axis(extra = {}) {
  const grid = color("--border");
  return { stroke: color("--muted"), grid: { stroke: grid, width: 1 }, ticks: { stroke: grid, width: 1 }, ...extra };
}

/** @typedef {{chart: UPlotChart, destroy(): void}} Chart */

/** Keep a chart as wide as its box. Returns a function that stops following it. */
function follow(box, chart, height) {
  const observer = new ResizeObserver(() => {
    const width = Math.max(200, box.clientWidth);
    if (width !== chart.width) chart.setSize({ width, height });
  });
  observer.observe(box);
  return () => observer.disconnect();
}

/**
 * A chart in `box` that tracks its width; {chart, destroy()}.
 * @param {UPlotStatic} uPlot
 * @param {HTMLElement} box
 * @param {{height: number} & Record<string, unknown>} options
 * @param {(number | null)[][]} data
 * @returns {Chart}
 */
function mount(uPlot, box, options, data) {
  box.replaceChildren();
  const height = options.height;
  const chart = new uPlot({ width: Math.max(200, box.clientWidth), ...options }, data, box);
  const unfollow = follow(box, chart, height);
  return {
    chart,
    destroy() {
      unfollow();
      chart.destroy();
    },
  };
}

/**
 * Lines over time. series: [{label, stroke (CSS variable), dash?}], data: [times (epoch
 * s), ...values] in uPlot's column layout (null: no value there).
 * @param {HTMLElement} box
 * @param {{series: {label: string, stroke: string, dash?: boolean}[], data: (number | null)[][],
 *   height?: number, unit?: string, window?: number, timeLabel?: string}} options
 * @returns {Promise<Chart>}
 */
export async function timeChart(box, { series, data, height = 180, unit = "", window = 0, timeLabel = "" }) {
  const uPlot = await loadCharts();
  // A fixed window (the last `window` seconds) keeps minute ticks even while the data is
  // only seconds long; uPlot would otherwise label fractions of a second.
  const x = window ? { time: true, range: (u, min, max) => [max - window, max] } : { time: true };
  const clock = (u, splits) => splits.map((v) => new Date(v * 1000).toLocaleTimeString([], { hour: "2-digit", minute: "2-digit" }));
  const options = {
    height,
    scales: { x },
    axes: [axis(window ? { values: clock, space: 60 } : {}), axis({ values: (u, splits) => splits.map((v) => `${v}${unit}`), size: 56 })],
    series: [
      timeLabel ? { label: timeLabel } : {}, // uPlot's own label is English ("Time")
      ...series.map((s) => ({
        label: s.label,
        stroke: color(s.stroke),
        width: s.dash ? 1 : 2,
        dash: s.dash ? [6, 4] : undefined,
        points: { show: false },
        value: (u, v) => (v === null || v === undefined ? "—" : `${v.toFixed(1)}${unit}`),
      })),
    ],
    legend: { live: true },
  };
  return mount(uPlot, box, options, data);
}

/**
 * Bars over categories (printers) or days. labels: the x labels; series: [{label, fill
 * (CSS variable), values}]; xLabel names the x value in the legend. stacked: each bar
 * stands on the ones before it. time: the labels are epoch seconds (UTC days). format(v)
 * writes a value for the legend and the axis.
 * @param {HTMLElement} box
 * @param {{labels: any[], series: {label: string, fill: string, values: (number | null)[]}[],
 *   xLabel?: string, stacked?: boolean, time?: boolean, height?: number,
 *   format?: (v: number) => string, max?: number}} options
 * @returns {Promise<Chart>}
 */
export async function barChart(box, { labels, series, xLabel = "", stacked = false, time = false, height = 220, format = String, max }) {
  const uPlot = await loadCharts();
  const xs = time ? labels : labels.map((_, i) => i);
  // Stacked: draw the running totals, tallest first, so each segment shows its own part.
  const shown = stacked ? cumulative(series.map((s) => s.values)) : series.map((s) => s.values);
  const order = stacked ? [...series.keys()].reverse() : [...series.keys()];
  const bars = uPlot.paths.bars({ size: [0.7, 60], align: 0 });
  const half = time ? 43200 : 0.5;
  const options = {
    height,
    scales: {
      x: { time, range: () => (xs.length ? [xs[0] - half, xs[xs.length - 1] + half] : [0, 1]) },
      y: { range: (u, min, mx) => [0, max ?? Math.max(1, mx)] },
    },
    axes: [
      axis(
        time
          ? {}
          : { splits: () => xs, values: (u, splits) => splits.map((i) => labels[i] ?? ""), gap: 6 },
      ),
      axis({ values: (u, splits) => splits.map(format), size: 56 }),
    ],
    series: [
      time
        ? { label: xLabel, value: (u, v) => (v === null || v === undefined ? "—" : new Date(v * 1000).toISOString().slice(0, 10)) }
        : { label: xLabel, value: (u, v) => (v === null || v === undefined ? "—" : labels[v] ?? "—") },
      ...order.map((i) => ({
        label: series[i].label,
        fill: color(series[i].fill),
        stroke: color(series[i].fill),
        width: 0,
        paths: bars,
        points: { show: false },
        value: (u, v, s, idx) => (idx === null ? "—" : format(series[i].values[idx] ?? 0)),
      })),
    ],
    legend: { live: true },
  };
  return mount(uPlot, box, options, [xs, ...order.map((i) => shown[i])]);
}

function cumulative(columns) {
  const totals = [];
  let running = columns[0] ? columns[0].map(() => 0) : [];
  for (const column of columns) {
    running = running.map((sum, i) => sum + (column[i] ?? 0));
    totals.push(running);
  }
  return totals;
}
