// A printer's G-code console: send commands, watch the responses arrive (the /ws console
// subscription), errors with the backend's message. History with the arrow keys.
import { send } from "./actions.js";
import { h } from "./dom.js";
import { messageOf, t } from "./i18n.js";
import { watchConsole } from "./live.js";
import { can } from "./session.js";

const MAX_LINES = 500;
const history = [];
let current = null; // {id, log}

/** Fill `panel` with the console of printer `id` and subscribe to its responses. */
export function showConsole(panel, id) {
  const log = h("div", { class: "console-log", role: "log", "aria-live": "polite", "aria-label": t("console.log"), tabindex: "0" });
  const input = h("input", {
    type: "text",
    name: "script",
    class: "console-input",
    autocomplete: "off",
    spellcheck: false,
    "aria-label": t("console.input"),
    placeholder: t("console.placeholder"),
  });
  let cursor = history.length;
  input.addEventListener("keydown", (event) => {
    if (event.key === "ArrowUp" && cursor > 0) {
      cursor -= 1;
      input.value = history[cursor];
      event.preventDefault();
    } else if (event.key === "ArrowDown" && cursor < history.length) {
      cursor += 1;
      input.value = history[cursor] ?? "";
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
  form.addEventListener("submit", async (event) => {
    event.preventDefault();
    const script = input.value.trim();
    if (!script) return;
    if (history[history.length - 1] !== script) history.push(script);
    cursor = history.length;
    input.value = "";
    line(log, "sent", `> ${script}`);
    try {
      // A 409 confirmation_required (e.g. a move outside the build volume) asks first and
      // is sent again with confirm: true only when the user goes ahead (null otherwise).
      const result = await send(id, "gcode", { script }, false, false);
      if (result) line(log, "ok", `${t("console.done")} ${script}`);
      else line(log, "error", t("console.not_sent"));
    } catch (error) {
      line(log, "error", messageOf(error));
    }
  });
  const operator = can("operator");
  for (const control of form.querySelectorAll("input, button")) control.disabled = !operator;
  const hint = operator ? t("console.hint") : t("session.needs_operator");
  panel.replaceChildren(log, form, h("p", { class: "hint", text: hint }));
  current = { id, log };
  watchConsole([id]);
  return input;
}

/** Stop receiving responses (the console was closed). */
export function hideConsole() {
  current = null;
  watchConsole([]);
}

/** A gcode_response frame from /ws. */
export function consoleResponse(frame) {
  if (!current || frame.printer !== current.id) return;
  const kind = /^!!|^Error/i.test(frame.message) ? "error" : "response";
  line(current.log, kind, frame.message);
}

function line(log, kind, text) {
  const stick = log.scrollTop + log.clientHeight >= log.scrollHeight - 4;
  const time = new Date().toLocaleTimeString([], { hour12: false });
  log.append(h("div", { class: `line ${kind}` }, h("time", { text: time }), h("span", { text })));
  while (log.childElementCount > MAX_LINES) log.firstElementChild.remove();
  if (stick) log.scrollTop = log.scrollHeight;
}
