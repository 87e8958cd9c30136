// Spanish and English: follows the browser, switchable, remembered in localStorage.
import { STRINGS } from "./strings.js";

const STORAGE_KEY = "kybercore.lang";
const listeners = new Set();
let lang = initialLang();

function initialLang() {
  let stored = null;
  try {
    stored = localStorage.getItem(STORAGE_KEY);
  } catch {
    stored = null;
  }
  if (stored && stored in STRINGS) return stored;
  const wanted = (navigator.languages && navigator.languages[0]) || navigator.language || "en";
  return wanted.toLowerCase().startsWith("es") ? "es" : "en";
}

export function getLang() {
  return lang;
}

/** A translated string; {name} placeholders are filled from vars. With vars.n === 1 the
 * key's "_one" form is used where there is one ("1 printer", "1 seleccionada"). */
export function t(key, vars) {
  const one = vars?.n === 1 ? STRINGS[lang][`${key}_one`] : undefined;
  const text = one ?? STRINGS[lang][key] ?? STRINGS.en[key] ?? key;
  if (!vars) return text;
  return text.replace(/\{(\w+)\}/g, (match, name) => (name in vars ? String(vars[name]) : match));
}

export function setLang(next) {
  if (!(next in STRINGS) || next === lang) return;
  lang = next;
  try {
    localStorage.setItem(STORAGE_KEY, next);
  } catch {
    // private mode: the choice lasts for this page only
  }
  translateStatic(document);
  for (const fn of listeners) fn(lang);
}

export function onLangChange(fn) {
  listeners.add(fn);
}

/** Translate the static markup: data-i18n (text), data-i18n-<attr> (attributes). */
export function translateStatic(root) {
  document.documentElement.lang = lang;
  document.title = t("app.title");
  for (const el of root.querySelectorAll("[data-i18n]")) el.textContent = t(el.dataset.i18n);
  for (const attr of ["aria-label", "placeholder", "title"]) {
    const data = `data-i18n-${attr}`;
    for (const el of root.querySelectorAll(`[${data}]`)) el.setAttribute(attr, t(el.getAttribute(data)));
  }
}

/** A backend reason {en, es, ...} in the UI's language. */
export function reasonText(reason) {
  return (reason && (reason[lang] || reason.en)) || "";
}

/** A 422 field problem {field, en, es} in the UI's language, without pydantic's prefix. */
export function fieldText(problem) {
  return reasonText(problem).replace(/Value error, /, "");
}

/**
 * The backend's message for an error or a failed result: the reasons in the UI's
 * language when there are any (blocking ones first), then the per-field problems of an
 * invalid request, else the plain message.
 */
export function messageOf(error) {
  const reasons = (error && error.reasons) || [];
  const blocking = reasons.filter((r) => r.level === "block");
  const shown = blocking.length ? blocking : reasons.filter((r) => r.level === "warn");
  if (shown.length) return shown.map(reasonText).join(" ");
  const fields = (error && error.fields) || [];
  if (fields.length) return fields.map((f) => `${f.field}: ${fieldText(f)}`).join(" ");
  return (error && error.message) || t("error.unknown");
}
