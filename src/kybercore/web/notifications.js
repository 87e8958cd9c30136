// The Notifications page (#notifications): the channels KyberCore tells the farm's news to
// (add, edit, switch on and off, send a test, delete), the delivery log and noise control.
// Built on first use; relabelled on a language change, re-checked on a role change.
import { api } from "./api.js";
import { confirmDialog, toast } from "./dialogs.js";
import { byId, h, icon, setText } from "./dom.js";
import { messageOf, onLangChange, t } from "./i18n.js";
import { channelDialog } from "./notify_form.js";
import { SEVERITIES, kindLabel, loadKinds, selectableKinds } from "./notify_kinds.js";
import { initLog, refreshLog, relabelLog, setChannels, startLog, statusOf, stopLog } from "./notify_log.js";
import { initSettings, loadSettings, relabelSettings } from "./notify_settings.js";
import { can, onSessionChange } from "./session.js";
import { printers, subscribe } from "./store.js";

export const NOTIFY_HASH = "#notifications";
const SHOWN_EVENTS = 3; // event names listed on a channel before "and N more"

let els = null;
let shown = false;
let channels = [];
const rows = new Map(); // channel id -> ChannelRow

/** Show the page (`page` "notifications") or, for any other page, hide it. */
export function showNotificationsPage(page) {
  const root = byId("notifications-view");
  const show = page === "notifications";
  if (show && !els) build(root);
  root.hidden = !show;
  if (show === shown) return;
  shown = show;
  if (show) refresh();
  else stopLog();
}

/** Load what the user may see: channels and the log are an operator's, settings anyone's. */
function refresh() {
  loadSettings();
  els.logSection.hidden = !can("operator");
  if (!can("operator")) {
    stopLog();
    channels = [];
    for (const row of rows.values()) row.el.remove();
    rows.clear();
    showMessage();
    return;
  }
  loadChannels();
  startLog();
}

/** @param {HTMLElement} root */
function build(root) {
  const log = h("section", { class: "nt-section" });
  els = {
    root,
    title: h("h2", { id: "nt-title" }),
    intro: h("p", { class: "muted nt-intro" }),
    add: h("button", { type: "button", class: "btn primary", id: "nt-add", onclick: addChannel }, icon("plus"), h("span")),
    channelsTitle: h("h3", { id: "nt-channels-title", tabindex: "-1" }),
    list: h("ul", { class: "nt-channels", "aria-labelledby": "nt-channels-title" }),
    message: h("p", { class: "empty", role: "status" }),
    logSection: log,
  };
  const settings = h("section", { class: "nt-section" });
  root.setAttribute("aria-labelledby", "nt-title");
  root.append(
    h("header", { class: "ledger-head" }, els.title, h("span", { class: "toolbar-spacer" }), els.add),
    els.intro,
    h("section", { class: "nt-section", "aria-labelledby": "nt-channels-title" }, els.channelsTitle, els.list, els.message),
    log,
    settings,
  );
  initLog(log);
  initSettings(settings);
  relabel();
  onLangChange(() => {
    relabel();
    relabelLog();
    relabelSettings();
  });
  onSessionChange(() => {
    relabel();
    relabelSettings();
    if (shown) refresh();
  });
  // Printer names in the channels' filters arrive with the fleet's first frame.
  subscribe((change) => change.full && relabel());
}

function relabel() {
  setText(els.title, t("nt.title"));
  setText(els.intro, t("nt.intro"));
  setText(els.add.lastElementChild, t("nt.add"));
  setText(els.channelsTitle, t("nt.channels"));
  els.add.disabled = !can("operator");
  for (const row of rows.values()) row.update(row.channel);
  showMessage();
}

function showMessage(error) {
  const empty = can("operator") ? t("nt.no_channels") : t("nt.operators_only");
  const text = error ? messageOf(error) : channels.length ? "" : empty;
  setText(els.message, text);
  els.message.hidden = !text;
}

/** Fetch the kinds (for the labels) and the channels, and draw them. */
async function loadChannels() {
  let answer;
  try {
    await loadKinds();
    answer = await api.notifyChannels();
  } catch (error) {
    showMessage(error);
    return;
  }
  channels = answer;
  setChannels(channels);
  const seen = new Set();
  for (const channel of channels) {
    seen.add(channel.id);
    let row = rows.get(channel.id);
    if (!row) {
      row = new ChannelRow();
      rows.set(channel.id, row);
    }
    row.update(channel);
    els.list.append(row.el); // (moves an existing row) keeps the backend's order
  }
  for (const [id, row] of rows) {
    if (!seen.has(id)) {
      row.el.remove();
      rows.delete(id);
    }
  }
  showMessage();
}

async function addChannel() {
  const saved = await channelDialog();
  if (saved) await loadChannels();
}

/** One channel in the list; its elements are kept, so focus stays put on an update. */
class ChannelRow {
  constructor() {
    this.channel = null;
    this.busy = false; // a test message is on its way
    this.name = h("h4", { class: "nt-name" });
    this.kind = h("span", { class: "chip nt-kind" });
    this.enabled = h("input", { type: "checkbox", onchange: () => this.toggle() });
    this.enabledText = h("span");
    const fact = () => [h("dt"), h("dd")];
    this.facts = { target: fact(), events: fact(), filter: fact(), quiet: fact() };
    this.test = h("button", { type: "button", class: "btn small", onclick: () => this.sendTest() });
    this.edit = h("button", { type: "button", class: "btn small", onclick: () => this.editChannel() });
    this.remove = h("button", { type: "button", class: "btn small danger-text", onclick: () => this.deleteChannel() });
    this.outcome = h("p", { class: "nt-outcome", role: "status" });
    this.el = h(
      "li",
      { class: "nt-channel" },
      h("div", { class: "nt-channel-head" }, this.name, this.kind, h("label", { class: "check nt-switch" }, this.enabled, this.enabledText)),
      h("dl", { class: "nt-facts" }, Object.values(this.facts).map(([dt, dd]) => h("div", {}, dt, dd))),
      h("div", { class: "nt-actions" }, this.test, this.edit, this.remove),
      this.outcome,
    );
  }

  update(channel) {
    this.channel = channel;
    const id = `nt-channel-${channel.id}`;
    this.name.id = id;
    this.el.dataset.id = String(channel.id);
    this.el.dataset.kind = channel.kind;
    this.el.dataset.enabled = String(channel.enabled);
    setText(this.name, channel.name);
    setText(this.kind, t(`nt.kind.${channel.kind}`));
    const rules = channel.rules;
    const facts = [
      ["target", t("nt.target"), channel.target],
      ["events", t("nt.events"), eventsText(rules.events)],
      ["filter", t("nt.filter"), filterText(rules)],
      ["quiet", t("nt.quiet"), quietText(rules.quiet_hours)],
    ];
    for (const [key, label, value] of facts) {
      setText(this.facts[key][0], label);
      setText(this.facts[key][1], value);
    }
    this.facts.target[1].classList.add("nt-target");
    setText(this.enabledText, t("nt.enabled"));
    setText(this.test, t("nt.test"));
    setText(this.edit, t("nt.edit"));
    setText(this.remove, t("nt.delete"));
    // The buttons say what they do; the channel's name (described-by) says to what.
    for (const control of [this.enabled, this.test, this.edit, this.remove]) control.setAttribute("aria-describedby", id);
    this.enabled.checked = channel.enabled;
    const mayChange = can(rules.min_role || "admin");
    this.enabled.disabled = !mayChange;
    this.edit.disabled = !mayChange;
    this.remove.disabled = !mayChange;
    this.test.disabled = !can("operator") || this.busy;
    this.el.title = mayChange ? "" : t("nt.locked");
  }

  say(text, outcome) {
    this.outcome.dataset.outcome = outcome;
    setText(this.outcome, text);
  }

  async toggle() {
    const enabled = this.enabled.checked;
    try {
      this.update(await api.updateNotifyChannel(this.channel.id, { enabled }));
      this.say("", "");
    } catch (error) {
      this.enabled.checked = !enabled;
      this.say(messageOf(error), "error");
    }
  }

  async sendTest() {
    this.busy = true;
    this.test.disabled = true;
    this.test.classList.add("busy");
    this.say(t("nt.testing"), "sending");
    try {
      const delivery = await api.testNotifyChannel(this.channel.id);
      const status = statusOf(delivery);
      this.say(testText(delivery, status), status);
    } catch (error) {
      this.say(messageOf(error), "error");
    } finally {
      this.busy = false;
      this.test.classList.remove("busy");
      this.test.disabled = !can("operator");
      refreshLog();
    }
  }

  async editChannel() {
    const saved = await channelDialog(this.channel);
    if (saved) await loadChannels();
  }

  async deleteChannel() {
    const channel = this.channel;
    const ok = await confirmDialog({
      title: t("nt.delete_title", { name: channel.name }),
      message: t("nt.delete_body"),
      confirmLabel: t("nt.delete"),
      danger: true,
    });
    if (!ok) return;
    try {
      await api.removeNotifyChannel(channel.id);
    } catch (error) {
      this.say(messageOf(error), "error");
      return;
    }
    toast({ kind: "ok", title: channel.name, message: t("nt.deleted") });
    // Focus goes to the next channel's first button, or to the list's heading.
    const next = this.el.nextElementSibling || this.el.previousElementSibling;
    await loadChannels();
    const target = next?.isConnected ? next.querySelector("button:not(:disabled)") : null;
    (target || els.channelsTitle).focus();
    refreshLog();
  }
}

function testText(delivery, status) {
  const error = delivery.last_error || (delivery.response_code ? `HTTP ${delivery.response_code}` : "");
  if (status === "delivered") return delivery.response_code ? t("nt.test_delivered_code", { code: delivery.response_code }) : t("nt.test_delivered");
  if (status === "retrying") return t("nt.test_retrying", { error });
  if (status === "failed") return t("nt.test_failed", { error });
  return t("nt.test_pending");
}

function eventsText(events) {
  const chosen = new Set(events);
  const all = selectableKinds();
  if (all.length && all.every((k) => chosen.has(k.kind))) return t("nt.all_events");
  if (!chosen.size) return t("nt.no_events");
  // Most severe first (those are what an operator checks for), then in the backend's order.
  const rank = (kind) => {
    const index = all.findIndex((k) => k.kind === kind);
    return index < 0 ? all.length * SEVERITIES.length : SEVERITIES.indexOf(all[index].severity) * all.length + index;
  };
  const names = [...chosen].sort((a, b) => rank(a) - rank(b)).map((k) => kindLabel(k));
  const list = names.slice(0, SHOWN_EVENTS).join(", ");
  return names.length > SHOWN_EVENTS ? t("nt.events_more", { list, more: names.length - SHOWN_EVENTS }) : list;
}

function filterText(rules) {
  const parts = [];
  const names = (rules.printers || []).map((id) => printers.get(id)?.name || id);
  if (names.length) parts.push(t("nt.filter_printers", { list: names.join(", ") }));
  if (rules.locations?.length) parts.push(t("nt.filter_locations", { list: rules.locations.join(", ") }));
  if (rules.tags?.length) parts.push(t("nt.filter_tags", { list: rules.tags.join(", ") }));
  return parts.length ? parts.join(" · ") : t("nt.all_printers");
}

function quietText(quiet) {
  if (!quiet) return t("nt.quiet_off");
  const range = t("nt.quiet_range", { start: quiet.start, end: quiet.end });
  return `${range} · ${t(quiet.allow_critical === false ? "nt.quiet_silent" : "nt.quiet_critical")}`;
}
