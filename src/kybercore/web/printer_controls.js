// The printer page's hands-on panels: toolhead (home, jog), extruder (extrude, retract),
// fan and factors (fan, speed, flow, Z babystep) and the printer's macros. Each button sends
// G-code through the validated G-code route; a button that cannot work now is disabled
// with the reason next to it (not homed, printing, hotend too cold, printer not ready).
import { api } from "./api.js";
import { showSpool } from "./cards.js";
import { consoleCommand } from "./console.js";
import { toast } from "./dialogs.js";
import { h, setHidden, setText } from "./dom.js";
import { messageOf, t } from "./i18n.js";
import { can } from "./session.js";
import { printers } from "./store.js";

const STEPS = [0.1, 1, 10, 100];
const AXES = ["X", "Y", "Z"];
const FEED = { X: 6000, Y: 6000, Z: 600 }; // mm/min: Mainsail's defaults
const Z_STEPS = [-0.05, -0.01, 0.01, 0.05];

/** Build the panels for printer `id`; returns {cards, ...refs} for updateControls. */
export function buildControls(id) {
  const refs = { id, step: 10, macrosLoaded: false };
  refs.cards = [toolhead(refs), extruder(refs), tune(refs), macros(refs)];
  return refs;
}

/** A panel of the printer page: a section named by its heading. */
export function card(key, title, ...body) {
  return h("section", { class: "pp-card", id: key, "aria-labelledby": `${key}-title` }, h("h2", { id: `${key}-title`, text: title }), ...body);
}

function toolhead(refs) {
  refs.position = h("p", { class: "pp-position", "aria-live": "off" });
  refs.homed = h("p", { class: "pp-homed" });
  refs.homeAll = h("button", { type: "button", class: "btn small", dataset: { home: "" }, onclick: () => gcode(refs, "G28") }, t("pp.home_all"));
  const homeAxes = AXES.map((axis) => h("button", { type: "button", class: "btn small", dataset: { home: axis }, onclick: () => gcode(refs, `G28 ${axis}`) }, t("pp.home_axis", { axis })));
  const steps = h(
    "div",
    { class: "pp-steps", role: "radiogroup", "aria-label": t("pp.step") },
    STEPS.map((step) =>
      h("label", { class: "pp-step" }, h("input", { type: "radio", name: `step-${refs.id}`, value: String(step), checked: step === refs.step, onchange: () => (refs.step = step) }), h("span", { text: String(step) })),
    ),
  );
  refs.jog = [];
  const grid = h("div", { class: "pp-jog" });
  for (const axis of AXES) {
    for (const dir of [-1, 1]) {
      const button = h("button", {
        type: "button",
        class: "btn small pp-jog-btn",
        dataset: { axis, dir: String(dir) },
        text: `${axis}${dir < 0 ? "−" : "+"}`,
        onclick: () => gcode(refs, `G91\nG1 ${axis}${dir * refs.step} F${FEED[axis]}\nG90`),
      });
      refs.jog.push(button);
      grid.append(button);
    }
  }
  refs.homeButtons = [refs.homeAll, ...homeAxes];
  refs.moveHint = h("p", { class: "pp-hint", role: "note" });
  return card("pp-toolhead", t("pp.toolhead"), refs.position, refs.homed, h("div", { class: "pp-row" }, ...refs.homeButtons), h("p", { class: "pp-label", text: t("pp.step") }), steps, grid, refs.moveHint);
}

function extruder(refs) {
  refs.length = h("input", { type: "number", min: "0.1", max: "200", step: "0.1", value: "10", inputmode: "decimal", class: "pp-num" });
  refs.speed = h("input", { type: "number", min: "0.5", max: "50", step: "0.5", value: "5", inputmode: "decimal", class: "pp-num" });
  const move = (sign) => {
    const length = Number(refs.length.value);
    const speed = Number(refs.speed.value);
    if (!(length > 0) || !(speed > 0)) return;
    gcode(refs, `M83\nG1 E${sign * length} F${Math.round(speed * 60)}`);
  };
  refs.extrude = h("button", { type: "button", class: "btn small", onclick: () => move(1) }, t("pp.extrude"));
  refs.retract = h("button", { type: "button", class: "btn small", onclick: () => move(-1) }, t("pp.retract"));
  refs.extrudeHint = h("p", { class: "pp-hint", role: "note" });
  refs.spool = h("span", { class: "badge spool", hidden: true });
  return card(
    "pp-extruder",
    t("pp.extruder"),
    refs.spool,
    h("div", { class: "pp-row" }, h("label", { class: "pp-field" }, h("span", { text: t("pp.length") }), refs.length), h("label", { class: "pp-field" }, h("span", { text: t("pp.speed_mms") }), refs.speed)),
    h("div", { class: "pp-row" }, refs.retract, refs.extrude),
    refs.extrudeHint,
  );
}

/** A percentage field with its own Set button: fan (M106), speed (M220), flow (M221). */
function percentField(refs, key, label, max, script) {
  const input = h("input", { type: "number", min: "0", max: String(max), step: "1", inputmode: "numeric", class: "pp-num" });
  const current = h("output", { class: "pp-current" });
  const form = h(
    "form",
    {
      class: "pp-percent",
      dataset: { field: key },
      onsubmit: (event) => {
        event.preventDefault();
        if (input.value === "") return;
        gcode(refs, script(Number(input.value))).then((ok) => {
          if (ok) input.value = "";
        });
      },
    },
    h("label", { class: "pp-field" }, h("span", { text: label }), input),
    current,
    h("button", { type: "submit", class: "btn small", text: t("pp.set") }),
  );
  refs[key] = { form, current };
  return form;
}

function tune(refs) {
  const fan = percentField(refs, "fan", t("pp.fan"), 100, (v) => `M106 S${Math.round((Math.min(v, 100) / 100) * 255)}`);
  const speed = percentField(refs, "speedFactor", t("pp.speed_factor"), 500, (v) => `M220 S${Math.round(v)}`);
  const flow = percentField(refs, "flow", t("pp.flow"), 200, (v) => `M221 S${Math.round(v)}`);
  refs.zOffset = h("output", { class: "pp-current pp-zoffset" });
  refs.zButtons = Z_STEPS.map((delta) =>
    h("button", {
      type: "button",
      class: "btn small",
      text: `${delta > 0 ? "+" : "−"}${Math.abs(delta)}`,
      "aria-label": t("pp.z_adjust", { delta: `${delta > 0 ? "+" : "−"}${Math.abs(delta)}` }),
      onclick: () => gcode(refs, `SET_GCODE_OFFSET Z_ADJUST=${delta} MOVE=1`),
    }),
  );
  refs.zReset = h("button", { type: "button", class: "btn small ghost", text: t("pp.z_reset"), onclick: () => gcode(refs, "SET_GCODE_OFFSET Z=0 MOVE=1") });
  const z = h("div", { class: "pp-z" }, h("span", { class: "pp-label", text: t("pp.z_offset") }), refs.zOffset, h("div", { class: "pp-row" }, ...refs.zButtons, refs.zReset));
  return card("pp-tune", t("pp.tune"), fan, speed, flow, z);
}

function macros(refs) {
  refs.macroBox = h("div", { class: "pp-macros" });
  refs.macroNote = h("p", { class: "pp-hint", role: "note" });
  return card("pp-macros", t("pp.macros"), refs.macroBox, refs.macroNote);
}

async function loadMacros(refs) {
  refs.macrosLoaded = true;
  let list;
  try {
    list = await api.macros(refs.id);
  } catch (error) {
    refs.macrosLoaded = false; // try again when the printer is next ready
    setText(refs.macroNote, messageOf(error));
    return;
  }
  refs.macroBox.replaceChildren(
    ...list.map((macro) =>
      h("button", {
        type: "button",
        class: "btn small pp-macro",
        dataset: { macro: macro.name },
        title: macro.description || macro.name,
        text: macro.name,
        disabled: !can("operator"),
        onclick: () => gcode(refs, macro.name),
      }),
    ),
  );
  setText(refs.macroNote, list.length ? "" : t("pp.macros_none"));
}

/** Send G-code through the page's console (logged there with Klipper's answer); what went
 * wrong is also a toast, as the console may be out of sight. Returns whether it worked. */
async function gcode(refs, script) {
  const { ok, problem } = await consoleCommand(refs.id, script);
  if (problem) toast({ kind: "error", title: `${printers.get(refs.id)?.name || refs.id} · ${t("action.gcode")}`, message: problem });
  return ok;
}

/** Enable what can work now and say why the rest cannot. */
export function updateControls(refs, p) {
  const ready = p.connection === "online" && p.klippy_state === "ready";
  const operator = can("operator");
  const busy = p.job?.state === "printing" || p.job?.state === "paused";
  const homed = (p.toolhead?.homed_axes || "").toUpperCase();
  const position = p.toolhead?.position;
  setText(refs.position, position ? AXES.map((axis, i) => `${axis} ${position[i].toFixed(2)}`).join("  ") : "—");
  setText(refs.homed, homed ? t("pp.homed", { axes: homed.split("").join(" ") }) : t("pp.homed_none"));
  for (const button of refs.homeButtons) button.disabled = !operator || !ready || busy;
  const missing = AXES.filter((axis) => !homed.includes(axis));
  for (const button of refs.jog) button.disabled = !operator || !ready || busy || !homed.includes(button.dataset.axis);
  let moveHint = "";
  if (!ready) moveHint = t("pp.hint.offline");
  else if (busy) moveHint = t("pp.hint.printing");
  else if (missing.length) moveHint = t("pp.hint.not_homed", { axes: missing.join(" ") });
  setText(refs.moveHint, moveHint);
  showSpool(refs.spool, p.spool);
  const canExtrude = ready && !busy && p.can_extrude;
  refs.extrude.disabled = refs.retract.disabled = !operator || !canExtrude;
  setText(refs.extrudeHint, !ready ? t("pp.hint.offline") : busy ? t("pp.hint.printing") : p.can_extrude ? "" : t("pp.hint.cold"));
  const percent = (v) => (typeof v === "number" ? `${Math.round(v * 100)} %` : "—");
  setText(refs.fan.current, percent(p.fan_speed));
  setText(refs.speedFactor.current, percent(p.speed_factor));
  setText(refs.flow.current, percent(p.extrude_factor));
  setText(refs.zOffset, typeof p.z_offset === "number" ? `${p.z_offset.toFixed(3)} mm` : "—");
  for (const form of [refs.fan.form, refs.speedFactor.form, refs.flow.form]) for (const field of form.elements) field.disabled = !operator || !ready;
  for (const button of [...refs.zButtons, refs.zReset]) button.disabled = !operator || !ready;
  for (const button of refs.macroBox.querySelectorAll("button")) button.disabled = !operator || !ready;
  if (ready && !refs.macrosLoaded) loadMacros(refs);
  setHidden(refs.macroNote, false);
  if (!ready && !refs.macroBox.childElementCount) setText(refs.macroNote, t("pp.macros_offline"));
}
