// Who is using the dashboard. On loopback without tokens KyberCore is open (everyone is
// admin); otherwise a token logs the browser in (an HttpOnly cookie set by POST
// /api/session) with a role: viewer (watch), operator (print actions) or admin (printers).
import { api } from "./api.js";
import { modal } from "./dialogs.js";
import { h } from "./dom.js";
import { messageOf, t } from "./i18n.js";

const RANK = { viewer: 0, operator: 1, admin: 2 };
let session = { access: "open", name: "local", role: "admin" };
let asking = null;
const listeners = new Set();

export function currentSession() {
  return session;
}

/** Whether the current user holds at least `role`. */
export function can(role) {
  return session.role in RANK && RANK[session.role] >= RANK[role];
}

export function onSessionChange(fn) {
  listeners.add(fn);
}

function set(next) {
  session = next;
  for (const fn of listeners) fn(session);
}

/** Ask the backend who we are; false when it could not be reached. */
export async function loadSession() {
  try {
    set(await api.session());
    return true;
  } catch {
    return false;
  }
}

export function needsLogin() {
  return session.access === "tokens" && !session.role;
}

/** Ask for a token until one is accepted (one dialog at a time). */
export function login() {
  if (!asking) {
    asking = loginDialog().finally(() => {
      asking = null;
    });
  }
  return asking;
}

async function loginDialog() {
  const input = h("input", { type: "password", name: "token", autocomplete: "current-password", required: true, spellcheck: false });
  const error = h("p", { class: "form-error", role: "alert", hidden: true });
  const result = await modal({
    title: t("session.title"),
    body: h(
      "div",
      { class: "form-grid" },
      h("p", { class: "hint", text: t("session.explain") }),
      h("label", { class: "field" }, h("span", { text: t("session.token") }), input),
      error,
    ),
    buttons: [{ label: t("session.login"), value: "login", kind: "primary" }],
    onSubmit: async () => {
      const token = input.value.trim();
      if (!token) {
        error.textContent = t("session.need_token");
        error.hidden = false;
        return false;
      }
      try {
        set(await api.login(token));
        return "ok";
      } catch (err) {
        error.textContent = messageOf(err);
        error.hidden = false;
        input.select();
        return false;
      }
    },
  });
  if (result !== "ok") await loadSession();
  return !needsLogin();
}

export async function logout() {
  try {
    await api.logout();
  } finally {
    await loadSession();
  }
}
