// Add and edit a notification channel (a dialog), and the webhook secret shown once, right
// after it was created. Validation is the backend's: the problems of its 422 answer go under
// the fields they name (rules.events, target...). Targets and secrets are write-only: an edit
// leaves them empty, and an empty one keeps what is stored.
import { api } from "./api.js";
import { modal, toast } from "./dialogs.js";
import { h } from "./dom.js";
import { getLang, t } from "./i18n.js";
import { SEVERITIES, defaultKinds, kindLabel, selectableKinds } from "./notify_kinds.js";
import { showErrors } from "./printer_form.js";
import { can } from "./session.js";
import { facets, printers } from "./store.js";

const LANGUAGES = { en: "English", es: "Español" };

/** A labelled control in a box the 422 problems can find (data-field = the API's path). */
function field(path, label, input, hint) {
  const id = `ntf-${path.replace(/\W/g, "-")}`;
  input.id = input.id || id;
  const error = h("p", { class: "field-error", id: `${id}-error`, hidden: true });
  const help = hint === undefined ? null : h("p", { class: "hint", id: `${id}-hint`, text: hint });
  if (help) input.setAttribute("aria-describedby", help.id);
  return h("div", { class: "field", dataset: { field: path } }, h("label", { for: input.id, text: label }), input, help, error);
}

/** A fieldset of checkboxes named `name`, one per [value, label]. */
function picks(path, name, legend, options, chosen, extra = {}) {
  const ticked = new Set(chosen);
  const boxes = options.map(([value, label]) =>
    h("label", { class: "check" }, h("input", { type: "checkbox", name, value, checked: ticked.has(value) }), h("span", { text: label })),
  );
  return h(
    "fieldset",
    { class: `nt-picks ${extra.class || ""}`.trim(), dataset: path ? { field: path } : {} },
    h("legend", { text: legend }),
    boxes.length ? h("div", { class: "nt-pick-list" }, boxes) : h("p", { class: "hint", text: t("nt.form.none_known") }),
    h("p", { class: "field-error", hidden: true }),
  );
}

function eventsBox(chosen) {
  const kinds = selectableKinds();
  return h(
    "fieldset",
    { class: "nt-group", dataset: { field: "rules.events" } },
    h("legend", { text: t("nt.form.events") }),
    h("p", { class: "hint", text: t("nt.form.events_hint") }),
    h("p", { class: "field-error", hidden: true }),
    h(
      "div",
      { class: "nt-severities" },
      SEVERITIES.map((severity) => {
        const mine = kinds.filter((k) => k.severity === severity).map((k) => [k.kind, kindLabel(k.kind)]);
        return mine.length ? picks(null, "events", t(`nt.severity.${severity}`), mine, chosen, { class: `sev-${severity}` }) : null;
      }),
    ),
  );
}

function filtersBox(rules) {
  const fleet = [...printers.values()].sort((a, b) => a.name.localeCompare(b.name)).map((p) => [p.id, p.name]);
  const known = facets();
  // Filters naming printers, places or tags the fleet no longer has stay visible (and kept).
  const withChosen = (options, chosen) => [...options, ...chosen.filter((c) => !options.some(([v]) => v === c)).map((c) => [c, c])];
  const pairs = (list) => list.map((x) => [x, x]);
  return h(
    "fieldset",
    { class: "nt-group" },
    h("legend", { text: t("nt.form.filters") }),
    h("p", { class: "hint", text: t("nt.form.filters_hint") }),
    h(
      "div",
      { class: "nt-filters" },
      picks("rules.printers", "printers", t("nt.form.printers"), withChosen(fleet, rules.printers), rules.printers),
      picks("rules.locations", "locations", t("nt.form.locations"), withChosen(pairs(known.locations), rules.locations), rules.locations),
      picks("rules.tags", "tags", t("nt.form.tags"), withChosen(pairs(known.tags), rules.tags), rules.tags),
    ),
  );
}

function quietBox(quiet) {
  const on = h("input", { type: "checkbox", name: "quiet_on", checked: Boolean(quiet) });
  const start = h("input", { type: "time", name: "quiet_start", value: quiet?.start || "22:00" });
  const end = h("input", { type: "time", name: "quiet_end", value: quiet?.end || "07:00" });
  const critical = h("input", { type: "checkbox", name: "quiet_critical", checked: quiet ? quiet.allow_critical !== false : true });
  const times = h(
    "div",
    { class: "nt-quiet-times" },
    field("rules.quiet_hours.start", t("nt.form.quiet_start"), start),
    field("rules.quiet_hours.end", t("nt.form.quiet_end"), end),
    h("label", { class: "check" }, critical, h("span", { text: t("nt.form.quiet_critical") })),
  );
  const sync = () => {
    for (const input of [start, end, critical]) input.disabled = !on.checked;
  };
  on.addEventListener("change", sync);
  sync();
  return h(
    "fieldset",
    { class: "nt-group", dataset: { field: "rules.quiet_hours" } },
    h("legend", { text: t("nt.form.quiet") }),
    h("label", { class: "check" }, on, h("span", { text: t("nt.form.quiet_on") })),
    h("p", { class: "field-error", hidden: true }),
    times,
    h("p", { class: "hint", text: t("nt.form.quiet_hint") }),
  );
}

function messageBox(rules, enabled) {
  const language = h("select", { name: "language" }, Object.entries(LANGUAGES).map(([value, label]) => h("option", { value, selected: rules.language === value }, label)));
  const role = h(
    "select",
    { name: "min_role" },
    h("option", { value: "operator", selected: rules.min_role === "operator" }, t("nt.form.role_operator")),
    // An operator cannot hand a channel over to admins only: the backend would refuse it.
    h("option", { value: "admin", selected: rules.min_role === "admin", disabled: !can("admin") }, t("nt.form.role_admin")),
  );
  return h(
    "fieldset",
    { class: "nt-group nt-message" },
    h("legend", { text: t("nt.form.message") }),
    field("rules.language", t("nt.form.language"), language),
    field("rules.min_role", t("nt.form.min_role"), role),
    h("label", { class: "check" }, h("input", { type: "checkbox", name: "snapshot", checked: rules.attach_snapshot }), h("span", { text: t("nt.form.snapshot") })),
    h("label", { class: "check" }, h("input", { type: "checkbox", name: "enabled", checked: enabled }), h("span", { text: t("nt.form.enabled") })),
  );
}

/** The kind radios (a new channel) or the kind as text (an existing one cannot change). */
function kindBox(channel) {
  if (channel) return h("p", { class: "nt-kind-fixed" }, h("strong", { text: `${t("nt.form.kind")}: ` }), t(`nt.kind.${channel.kind}`));
  const radio = (value) =>
    h("label", { class: "check" }, h("input", { type: "radio", name: "kind", value, checked: value === "webhook" }), h("span", { text: t(`nt.form.kind_${value}`) }));
  return h("fieldset", { class: "nt-group nt-kinds", dataset: { field: "kind" } }, h("legend", { text: t("nt.form.kind") }), radio("webhook"), radio("apprise"), h("p", { class: "field-error", hidden: true }));
}

function buildForm(channel) {
  const rules = channel?.rules || {
    events: defaultKinds(),
    printers: [],
    locations: [],
    tags: [],
    quiet_hours: null,
    language: getLang(),
    attach_snapshot: true,
    min_role: can("admin") ? "admin" : "operator",
  };
  const target = h("input", { type: "text", name: "target", inputmode: "url", autocomplete: "off", spellcheck: false, required: !channel, placeholder: channel?.target || "" });
  const secret = h("input", { type: "password", name: "secret", autocomplete: "new-password", placeholder: channel?.has_secret ? t("nt.form.secret_keep") : t("nt.form.secret_placeholder") });
  const targetBox = field("target", t("nt.form.url"), target, "");
  const secretBox = field("secret", t("nt.form.secret"), secret, t("nt.form.secret_hint"));
  const root = h(
    "div",
    { class: "form-grid nt-form" },
    h("p", { class: "form-error", role: "alert", hidden: true }),
    kindBox(channel),
    field("name", t("nt.form.name"), h("input", { type: "text", name: "name", value: channel?.name || "", required: true, autocomplete: "off", placeholder: t("nt.form.name_placeholder") })),
    targetBox,
    secretBox,
    eventsBox(rules.events),
    filtersBox(rules),
    quietBox(rules.quiet_hours),
    messageBox(rules, channel ? channel.enabled : true),
  );
  // The URL's examples and the secret follow the kind.
  const sync = () => {
    const kind = channel?.kind || /** @type {HTMLInputElement} */ (root.querySelector("input[name=kind]:checked")).value;
    const keep = channel ? ` ${t("nt.form.url_keep")}` : "";
    /** @type {HTMLElement} */ (targetBox.querySelector(".hint")).textContent = t(`nt.form.url_hint_${kind}`) + keep;
    if (!channel) target.placeholder = kind === "webhook" ? "https://" : "ntfy://";
    secretBox.hidden = kind !== "webhook";
  };
  for (const radio of root.querySelectorAll("input[name=kind]")) radio.addEventListener("change", sync);
  sync();
  return root;
}

/** The form's values: {kind, name, target, secret, enabled, rules}. */
function read(form, channel) {
  const el = form.elements;
  const ticked = (name) => [...form.querySelectorAll(`input[name="${name}"]:checked`)].map((input) => input.value);
  const quiet = el.quiet_on.checked ? { start: el.quiet_start.value, end: el.quiet_end.value, allow_critical: el.quiet_critical.checked } : null;
  return {
    kind: channel?.kind || form.querySelector("input[name=kind]:checked").value,
    name: el.name.value.trim(),
    target: el.target.value.trim(),
    secret: el.secret.value,
    enabled: el.enabled.checked,
    rules: {
      events: ticked("events"),
      printers: ticked("printers"),
      locations: ticked("locations"),
      tags: ticked("tags"),
      quiet_hours: quiet,
      language: el.language.value,
      attach_snapshot: el.snapshot.checked,
      min_role: el.min_role.value,
    },
  };
}

/** Mistakes worth saying before asking the backend, as 422-like field problems. */
function problems(values) {
  const found = [];
  const say = (field, key) => found.push({ field, en: t(key), es: t(key) });
  if (!values.rules.events.length) say("rules.events", "nt.form.no_events");
  const quiet = values.rules.quiet_hours;
  if (quiet && (!quiet.start || !quiet.end)) say("rules.quiet_hours", "nt.form.quiet_needs_times");
  return found;
}

/** Rules in one order (lists sorted), to tell whether an edit changed them. */
function canonical(rules) {
  const sorted = (list) => [...(list || [])].sort();
  const q = rules.quiet_hours;
  return JSON.stringify([
    sorted(rules.events),
    sorted(rules.printers),
    sorted(rules.locations),
    sorted(rules.tags),
    q ? [q.start, q.end, q.allow_critical !== false] : null,
    rules.language,
    Boolean(rules.attach_snapshot),
    rules.min_role,
  ]);
}

function createBody(v) {
  const body = { name: v.name, kind: v.kind, target: v.target, enabled: v.enabled, rules: v.rules };
  if (v.kind === "webhook" && v.secret) body.secret = v.secret;
  return body;
}

/** Only what changed: an empty URL or secret keeps the stored one. */
function patchBody(channel, v) {
  const body = {};
  if (v.name !== channel.name) body.name = v.name;
  if (v.target) body.target = v.target;
  if (v.secret) body.secret = v.secret;
  if (v.enabled !== channel.enabled) body.enabled = v.enabled;
  if (canonical(v.rules) !== canonical(channel.rules)) body.rules = v.rules;
  return body;
}

/**
 * A channel as the API shows it (ChannelOut; `secret` only in the answer to a create).
 * @typedef {object} Channel
 * @property {number} id
 * @property {string} name
 * @property {string} kind "webhook" or "apprise"
 * @property {string} target masked
 * @property {boolean} has_secret
 * @property {{events: string[], printers: string[], locations: string[], tags: string[],
 *   quiet_hours: {start: string, end: string, allow_critical: boolean} | null,
 *   language: string, attach_snapshot: boolean, min_role: string}} rules
 * @property {boolean} enabled
 * @property {string} created_at
 * @property {string} created_by
 * @property {string | null} [updated_at]
 * @property {string | null} [updated_by]
 * @property {string | null} [secret]
 */

/**
 * Add a channel (no argument) or edit one; resolves with the saved channel, or null.
 * @param {Channel} [channel]
 * @returns {Promise<Channel | null>}
 */
export async function channelDialog(channel) {
  /** @type {Channel | null} */
  let saved = null;
  /** @type {string | null} */
  let secret = null;
  await modal({
    title: channel ? t("nt.form.edit_title", { name: channel.name }) : t("nt.form.add_title"),
    body: buildForm(channel),
    wide: true,
    focus: "input[name=name]",
    buttons: [
      { label: t("action.back"), cancel: true },
      { label: channel ? t("nt.form.save") : t("nt.form.add"), value: "save", kind: "primary" },
    ],
    onSubmit: async (_choice, form) => {
      const values = read(form, channel);
      const found = problems(values);
      if (found.length) {
        showErrors(form, { fields: found });
        return false;
      }
      try {
        if (channel) {
          const body = patchBody(channel, values);
          saved = Object.keys(body).length ? await api.updateNotifyChannel(channel.id, body) : channel;
        } else {
          /** @type {Channel} */
          const created = await api.addNotifyChannel(createBody(values));
          saved = created;
          secret = created.secret || null;
        }
      } catch (error) {
        showErrors(form, error);
        return false;
      }
      return "saved";
    },
  });
  // onSubmit set them (TypeScript's flow analysis does not follow into the callback).
  const done = /** @type {Channel | null} */ (saved);
  const shownOnce = /** @type {string | null} */ (secret);
  if (!done) return null;
  toast({ kind: "ok", title: done.name, message: t(channel ? "nt.saved" : "nt.added") });
  if (shownOnce) await secretDialog(done.name, shownOnce);
  return done;
}

/** The secret of a new webhook, the one time it can be seen, with a copy button. */
export async function secretDialog(name, secret) {
  const input = h("input", { type: "text", id: "nt-secret", class: "nt-secret", readonly: true, value: secret, spellcheck: false, autocomplete: "off" });
  input.addEventListener("focus", () => input.select());
  const status = h("p", { class: "hint", role: "status" });
  const copy = async () => {
    let copied = false;
    try {
      await navigator.clipboard.writeText(secret);
      copied = true;
    } catch {
      // No clipboard API (plain http on a LAN address): the old way, from the selection.
      input.focus();
      input.select();
      copied = document.execCommand("copy");
    }
    status.textContent = t(copied ? "nt.secret.copied" : "nt.secret.copy_failed");
  };
  await modal({
    title: t("nt.secret.title", { name }),
    body: h(
      "div",
      { class: "form-grid" },
      h("p", { class: "nt-once", text: t("nt.secret.note") }),
      h(
        "div",
        { class: "field" },
        h("label", { for: "nt-secret", text: t("nt.secret.label") }),
        h("div", { class: "nt-secret-row" }, input, h("button", { type: "button", class: "btn", onclick: copy }, t("nt.secret.copy"))),
      ),
      status,
    ),
    buttons: [{ label: t("action.done"), value: "done", kind: "primary" }],
    focus: "#nt-secret",
  });
}
