// A printer's plate gate on its tile or table row. Awaiting a clear: one click says the
// print is good (the copy counts), "Bad…" asks for an optional cause (the copy is printed
// again). Held: who held it and why, and Release. Hold lives in the card's "more" menu.
import { api } from "./api.js";
import { modal, toast } from "./dialogs.js";
import { h, icon, setAttr, setHidden, setText } from "./dom.js";
import { getLang, messageOf, t } from "./i18n.js";
import { refreshQueue } from "./queue_data.js";
import { can } from "./session.js";
import { gates, printers } from "./store.js";

/** Card actions handled here (see actions.js: onCardAction). */
export const GATE_ACTIONS = new Set(["clear_good", "clear_bad", "hold", "release"]);

const nameOf = (id) => printers.get(id)?.name || id;

/** "14:02", or a date and time when it was not today. */
export function sinceText(iso) {
  const when = new Date(iso);
  if (Number.isNaN(when.getTime())) return "";
  const today = when.toDateString() === new Date().toDateString();
  /** @type {Intl.DateTimeFormatOptions} */
  const options = today ? { hour: "2-digit", minute: "2-digit" } : { dateStyle: "short", timeStyle: "short" };
  return new Intl.DateTimeFormat(getLang(), options).format(when);
}

/** How the print on the plate ended ("completed", "failed: <why>"), in the UI's language. */
function endedText(reason) {
  const match = /^(completed|failed|cancelled)(?:: (.*))?$/s.exec(reason || "");
  if (!match) return reason || "";
  return [t(`gate.ended.${match[1]}`), match[2]].filter(Boolean).join(": ");
}

function gateButton(action, iconName, extra = "") {
  return h("button", { type: "button", class: `btn small ${extra}`.trim(), dataset: { action } }, icon(iconName), h("span"));
}

/** The gate line of one card; update(p) writes it only when something shown changed. */
export class GateStrip {
  constructor() {
    this.text = h("span", { class: "gate-text" });
    this.good = gateButton("clear_good", "check", "good");
    this.bad = gateButton("clear_bad", "close");
    this.release = gateButton("release", "resume");
    this.el = h("div", { class: "gate", hidden: true, role: "group" }, this.text, h("span", { class: "gate-actions" }, this.good, this.bad, this.release));
    this.key = null;
  }

  update(p, card) {
    const gate = gates.get(p.id);
    const state = gate?.state || "available";
    const key = `${state}|${gate?.since}|${gate?.reason}|${p.name}|${can("operator")}|${t("gate.good")}`;
    if (key === this.key) return;
    this.key = key;
    setAttr(card, "data-gate", state === "available" ? null : state);
    setHidden(this.el, state === "available");
    if (state === "available" || !gate) return; // no gate: available
    this.el.dataset.gate = state;
    const awaiting = state === "awaiting_clear";
    const since = t("gate.awaiting", { time: sinceText(gate.since) });
    const text = awaiting ? [since, endedText(gate.reason)].filter(Boolean).join(" — ") : t(`gate.${state}`, { reason: gate.reason });
    setText(this.text, text);
    setAttr(this.el, "aria-label", `${p.name}: ${text}`);
    setHidden(this.good, !awaiting);
    setHidden(this.bad, !awaiting);
    setHidden(this.release, awaiting);
    const operator = can("operator");
    /** @type {[HTMLButtonElement, string][]} */
    const buttons = [[this.good, "good"], [this.bad, "bad"], [this.release, "release"]];
    for (const [button, key] of buttons) {
      setText(button.lastElementChild, t(`gate.${key}`));
      const title = t(`gate.${key}_title`, { name: p.name });
      setAttr(button, "aria-label", title);
      setAttr(button, "title", operator ? title : `${title} — ${t("session.needs_operator")}`);
      button.disabled = !operator;
    }
  }
}

/** Run a gate action from a card: clear good/bad, hold, release. */
export async function gateAction(id, action) {
  const name = nameOf(id);
  let done;
  try {
    if (action === "clear_good") {
      await api.clearPlate(id, "good");
      done = t("done.clear_good");
    } else if (action === "clear_bad") {
      const cause = await askText({
        title: t("gate.bad_dialog", { name }),
        message: t("gate.bad_body"),
        label: t("gate.cause"),
        placeholder: t("gate.cause_placeholder"),
        confirmLabel: t("gate.bad_confirm"),
      });
      if (cause === null) return;
      await api.clearPlate(id, "bad", cause);
      done = t("done.clear_bad");
    } else if (action === "hold") {
      const reason = await askText({
        title: t("gate.hold_dialog", { name }),
        message: t("gate.hold_body"),
        label: t("gate.reason"),
        placeholder: t("gate.reason_placeholder"),
        confirmLabel: t("gate.hold_confirm"),
        required: true,
      });
      if (reason === null) return;
      await api.hold(id, reason);
      done = t("done.hold");
    } else {
      await api.release(id);
      done = t("done.release");
    }
  } catch (error) {
    toast({ kind: "error", title: `${name} · ${t(`action.${action}`)}`, message: messageOf(error) });
    return;
  }
  toast({ kind: "ok", title: name, message: done });
  refreshQueue(0);
}

/** A small dialog asking for one line of text; null when backed out of. */
async function askText({ title, message, label, placeholder, confirmLabel, required = false }) {
  const input = h("input", { type: "text", name: "text", maxlength: "500", placeholder, autocomplete: "off" });
  const error = h("p", { class: "form-error", role: "alert", hidden: true });
  const value = await modal({
    title,
    body: h("div", { class: "form-grid" }, h("p", { class: "confirm-message", text: message }), h("label", { class: "field" }, h("span", { text: label }), input), error),
    buttons: [
      { label: t("action.back"), cancel: true },
      { label: confirmLabel, value: "yes", kind: "primary" },
    ],
    onSubmit: () => {
      if (required && !input.value.trim()) {
        error.textContent = t("gate.need_reason");
        error.hidden = false;
        return false;
      }
      return "yes";
    },
  });
  return value === "yes" ? input.value.trim() : null;
}
