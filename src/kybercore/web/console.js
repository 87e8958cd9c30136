// A printer's G-code console: its recent history (Moonraker's G-code store), the commands
// sent from here with Klipper's answers, and the live responses of the /ws console
// subscription. The log lives as long as the console's printer stays the same: switching
// tabs, or closing and reopening the drawer, shows it again (still fed meanwhile); another
// printer's console starts from that printer's history. History with the arrow keys.
import { send } from "./actions.js";
import { api } from "./api.js";
import { h } from "./dom.js";
import { messageOf, t } from "./i18n.js";
import { watchConsole } from "./live.js";
import { can } from "./session.js";

const MAX_LINES = 500;
const HISTORY_LINES = 100;
// A line the G-code's answer brought before /ws did is skipped when /ws brings it, for
// this long; after that, the same text is a new line.
const OWED_MS = 10000;
// Klipper's ways of saying a command failed: "!! ..." lines, and unknown commands, which
// Klipper 0.12 reports as plain information ('// Unknown command:"FOO"') though nothing ran.
// The same rule as the backend's (kybercore.fleet.actions.klipper_errors).
const ERROR_LINE = /^\s*(?:!!|\/\/\s*Unknown command:)/;

const typed = []; // commands typed here, for the arrow keys
let state = null; // {id, entries, el, loading, early, running, owed}

/** Whether a response line says that the command failed. */
export function isErrorLine(text) {
  return ERROR_LINE.test(text);
}

/** Fill `panel` with the console of printer `id`; returns its input (to focus). */
export function showConsole(panel, id) {
  if (!state || state.id !== id) state = openLog(id);
  const log = h("div", { class: "console-log", role: "log", "aria-live": "polite", "aria-label": t("console.log"), tabindex: "0" });
  log.append(...state.entries.map(lineOf));
  if (state.loading) log.setAttribute("aria-busy", "true"); // no reading out 100 old lines
  state.el = log;
  const input = h("input", {
    type: "text",
    name: "script",
    class: "console-input",
    autocomplete: "off",
    spellcheck: false,
    "aria-label": t("console.input"),
    placeholder: t("console.placeholder"),
  });
  let cursor = typed.length;
  input.addEventListener("keydown", (event) => {
    if (event.key === "ArrowUp" && cursor > 0) {
      cursor -= 1;
      input.value = typed[cursor];
      event.preventDefault();
    } else if (event.key === "ArrowDown" && cursor < typed.length) {
      cursor += 1;
      input.value = typed[cursor] ?? "";
      event.preventDefault();
    }
  });
  const form = h(
    "form",
    { class: "console-form" },
    h("span", { class: "prompt", "aria-hidden": "true", text: ">" }),
    input,
    h("button", { type: "submit", class: "btn primary small", text: t("console.send") }),
  );
  const shown = state;
  form.addEventListener("submit", (event) => {
    event.preventDefault();
    const script = input.value.trim();
    if (!script) return;
    if (typed[typed.length - 1] !== script) typed.push(script);
    cursor = typed.length;
    input.value = "";
    run(shown, script);
  });
  const operator = can("operator");
  for (const control of /** @type {NodeListOf<HTMLInputElement | HTMLButtonElement>} */ (form.querySelectorAll("input, button"))) control.disabled = !operator;
  const hint = operator ? t("console.hint") : t("session.needs_operator");
  panel.replaceChildren(log, form, h("p", { class: "hint", text: hint }));
  log.scrollTop = log.scrollHeight;
  return input;
}

/** The console is no longer on screen; its printer's log is kept, and still fed. */
export function hideConsole() {
  if (state) state.el = null;
}

/** A gcode_response frame from /ws. */
export function consoleResponse(frame) {
  const s = state;
  if (!s || frame.printer !== s.id) return;
  const text = String(frame.message);
  for (const lines of s.running) lines.push(text);
  if (s.loading) {
    s.early.push(text);
    return;
  }
  const now = Date.now();
  s.owed = s.owed.filter((o) => o.until > now);
  const owed = s.owed.findIndex((o) => o.text === text);
  if (owed >= 0) s.owed.splice(owed, 1);
  else add(s, responseEntry(text));
}

function openLog(id) {
  const s = { id, entries: [], el: null, loading: true, early: [], running: new Set(), owed: [] };
  watchConsole([id]);
  api
    .console(id, HISTORY_LINES)
    .then((store) => loaded(s, store), (error) => loaded(s, [], error));
  return s;
}

/** The printer's history arrived: put it before what was logged while it loaded. */
function loaded(s, store, error = null) {
  const past = store.map((e) =>
    e.type === "command"
      ? { kind: "sent history", text: `> ${e.message}`, time: new Date(e.time * 1000) }
      : { ...responseEntry(e.message, new Date(e.time * 1000)), kind: `${kindOf(e.message)} history` },
  );
  if (error) past.push({ kind: "error", text: t("console.no_history", { error: messageOf(error) }), time: new Date() });
  // Responses /ws brought while the history loaded may be its last lines too.
  const responses = store.filter((e) => e.type !== "command").map((e) => e.message);
  const early = s.early.slice(overlap(responses, s.early));
  s.loading = false;
  s.early = [];
  s.entries = [...past, ...s.entries, ...early.map((text) => responseEntry(text))].slice(-MAX_LINES);
  if (s.el) {
    s.el.replaceChildren(...s.entries.map(lineOf));
    s.el.removeAttribute("aria-busy");
    s.el.scrollTop = s.el.scrollHeight;
  }
}

/** How many of `later`'s first lines are the last lines of `earlier`. */
function overlap(earlier, later) {
  for (let k = Math.min(earlier.length, later.length); k > 0; k -= 1) {
    const tail = earlier.slice(earlier.length - k);
    if (tail.every((text, i) => text === later[i])) return k;
  }
  return 0;
}

/**
 * Run `script` on printer `id` as if typed into its console (the printer page's buttons do),
 * so it is logged with Klipper's answer. Resolves to {ok, problem}: problem is what went
 * wrong, in words, or null (also when the user declined a confirmation).
 */
export function consoleCommand(id, script) {
  if (!state || state.id !== id) state = openLog(id);
  return run(state, script);
}

async function run(s, script) {
  add(s, { kind: "sent", text: `> ${script}` });
  const seen = []; // what /ws brought while the command ran
  s.running.add(seen);
  try {
    // A 409 confirmation_required (e.g. a move outside the build volume) asks first and
    // is sent again with confirm: true only when the user goes ahead (null otherwise).
    const result = await send(s.id, "gcode", { script }, false, false);
    if (!result) {
      add(s, { kind: "error", text: t("console.not_sent") });
      return { ok: false, problem: null };
    }
    const response = result.response || [];
    // /ws may lag behind the answer: show what it has not brought yet, and skip it then.
    const pending = [...seen];
    for (const text of response) {
      const at = pending.indexOf(text);
      if (at >= 0) {
        pending.splice(at, 1);
        continue;
      }
      add(s, responseEntry(text));
      s.owed.push({ text, until: Date.now() + OWED_MS });
    }
    const errors = response.filter(isErrorLine);
    add(s, { kind: errors.length ? "error" : "ok", text: `${t(errors.length ? "console.failed" : "console.done")} ${script}` });
    return { ok: !errors.length, problem: errors.length ? errors.join(" ") : null };
  } catch (error) {
    add(s, { kind: "error", text: messageOf(error) });
    return { ok: false, problem: messageOf(error) };
  } finally {
    s.running.delete(seen);
  }
}

function kindOf(text) {
  return isErrorLine(text) ? "error" : "response";
}

function responseEntry(text, time = new Date()) {
  return { kind: kindOf(text), text, time };
}

function add(s, entry) {
  entry.time ??= new Date();
  s.entries.push(entry);
  if (s.entries.length > MAX_LINES) s.entries.splice(0, s.entries.length - MAX_LINES);
  const log = s.el;
  if (!log) return;
  const stick = log.scrollTop + log.clientHeight >= log.scrollHeight - 4;
  log.append(lineOf(entry));
  while (log.childElementCount > MAX_LINES) log.firstElementChild.remove();
  if (stick) log.scrollTop = log.scrollHeight;
}

function lineOf(entry) {
  const time = entry.time.toLocaleTimeString([], { hour12: false });
  return h("div", { class: `line ${entry.kind}` }, h("time", { text: time }), h("span", { text: entry.text }));
}
