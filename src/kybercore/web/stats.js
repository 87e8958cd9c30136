// The Statistics view: how busy the printers were and how their jobs ended, as graphs
// (uPlot) over a chosen window, from the ledger (GET /api/stats): utilisation per printer,
// jobs per day by outcome, success rate per printer. Each graph also says what it shows in
// words (aria-label), for screen readers.
import { ApiError, api } from "./api.js";
import { barChart } from "./charts.js";
import { h, setText } from "./dom.js";
import { messageOf, t } from "./i18n.js";
import { printers } from "./store.js";
import { outcomeText } from "./history.js";

const WINDOWS = [7, 30, 90];
const OUTCOMES = [
  ["completed", "--ready"],
  ["cancelled", "--paused"],
  ["error", "--error"],
];
const DAY = 86400;

let els = null;
let graphs = [];
let asked = 0;

/** Build the view into its (empty) section. */
export function initStats(root) {
  const card = (id) => {
    const title = h("h3", { id: `${id}-title` });
    const box = h("div", { id, class: "chart", role: "img", "aria-labelledby": `${id}-title` });
    return { title, box, card: h("section", { class: "stats-card" }, title, box) };
  };
  els = {
    root,
    title: h("h2", { id: "stats-title" }),
    window: h("select", { id: "stats-window", onchange: () => load() }),
    message: h("p", { class: "empty", hidden: true }),
    utilisation: card("stats-utilisation"),
    perDay: card("stats-per-day"),
    success: card("stats-success"),
  };
  root.setAttribute("aria-labelledby", "stats-title");
  root.append(
    h("header", { class: "ledger-head" }, els.title, h("span", { class: "toolbar-spacer" }), els.window),
    els.message,
    h("div", { class: "stats-grid" }, els.utilisation.card, els.perDay.card, els.success.card),
  );
  relabelStats(false);
}

/** Show the view: load the window's figures and draw them. */
export function showStats() {
  load();
}

export function hideStats() {
  for (const graph of graphs) graph.destroy();
  graphs = [];
}

/** Labels in the current language; the graphs are redrawn with them when shown. */
export function relabelStats(redraw = true) {
  if (!els) return;
  setText(els.title, t("stats.title"));
  const days = Number(els.window.value) || 30;
  els.window.replaceChildren(...WINDOWS.map((d) => h("option", { value: String(d) }, t("stats.last_days", { days: d }))));
  els.window.value = String(days);
  els.window.setAttribute("aria-label", t("stats.window"));
  setText(els.utilisation.title, t("stats.utilisation"));
  setText(els.perDay.title, t("stats.per_day"));
  setText(els.success.title, t("stats.success"));
  if (redraw && graphs.length) load();
}

async function load() {
  const days = Number(els.window.value) || 30;
  const to = new Date();
  const from = new Date(to.getTime() - days * DAY * 1000);
  const window = { from: from.toISOString(), to: to.toISOString() };
  const mine = ++asked;
  els.root.setAttribute("aria-busy", "true");
  let byPrinter;
  let byDay;
  try {
    [byPrinter, byDay] = await Promise.all([
      api.stats({ ...window, group_by: "printer" }),
      api.stats({ ...window, group_by: "day" }),
    ]);
  } catch (error) {
    if (mine !== asked) return;
    els.root.removeAttribute("aria-busy");
    els.message.hidden = false;
    setText(els.message, error instanceof ApiError ? messageOf(error) : t("error.unknown"));
    return;
  }
  if (mine !== asked) return;
  els.message.hidden = true;
  hideStats();
  graphs = await Promise.all([drawUtilisation(byPrinter.rows), drawPerDay(byDay.rows, from, to), drawSuccess(byPrinter.rows)]);
  els.root.removeAttribute("aria-busy");
}

const percent = (v) => (v === null || v === undefined ? "—" : `${Math.round(v * 100)}%`);
const nameOf = (id) => printers.get(id)?.name || id;

function summary(box, title, parts) {
  box.setAttribute("aria-label", `${title}: ${parts.join(", ") || t("stats.no_data")}`);
  box.dataset.rows = String(parts.length);
}

function drawUtilisation(rows) {
  const names = rows.map((r) => nameOf(r.key));
  const values = rows.map((r) => r.utilisation ?? 0);
  summary(els.utilisation.box, t("stats.utilisation"), rows.map((r, i) => `${names[i]} ${percent(r.utilisation)}`));
  return barChart(els.utilisation.box, {
    labels: names,
    xLabel: t("history.printer"),
    series: [{ label: t("stats.utilisation_series"), fill: "--printing", values }],
    format: percent,
    max: 1,
  });
}

function drawSuccess(rows) {
  const names = rows.map((r) => nameOf(r.key));
  summary(els.success.box, t("stats.success"), rows.map((r, i) => `${names[i]} ${percent(r.success_rate)}`));
  return barChart(els.success.box, {
    labels: names,
    xLabel: t("history.printer"),
    series: [{ label: t("stats.success_series"), fill: "--ready", values: rows.map((r) => r.success_rate) }],
    format: percent,
    max: 1,
  });
}

/** Jobs per day, stacked by outcome; every day of the window has a bar, empty or not. */
function drawPerDay(rows, from, to) {
  const byKey = new Map(rows.map((r) => [r.key, r.jobs]));
  const days = [];
  for (let day = Math.floor(from.getTime() / 1000 / DAY) * DAY; day <= to.getTime() / 1000; day += DAY) days.push(day);
  const jobsOn = (day) => byKey.get(new Date(day * 1000).toISOString().slice(0, 10)) || {};
  const known = OUTCOMES.map(([o]) => o);
  const series = OUTCOMES.map(([outcome, fill]) => ({
    label: outcomeText(outcome),
    fill,
    values: days.map((d) => jobsOn(d)[outcome] || 0),
  }));
  series.push({
    label: t("stats.other"),
    fill: "--offline",
    values: days.map((d) => Object.entries(jobsOn(d)).reduce((sum, [o, n]) => (known.includes(o) ? sum : sum + n), 0)),
  });
  const parts = rows
    .filter((r) => Object.values(r.jobs).some((n) => n > 0))
    .map((r) => `${r.key}: ${Object.entries(r.jobs).filter(([, n]) => n > 0).map(([o, n]) => `${n} ${outcomeText(o)}`).join(" + ")}`);
  summary(els.perDay.box, t("stats.per_day"), parts);
  return barChart(els.perDay.box, {
    labels: days,
    xLabel: t("stats.day"),
    series,
    stacked: true,
    time: true,
    format: (v) => String(Math.round(v)),
  });
}
