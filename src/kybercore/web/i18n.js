// Spanish and English: follows the browser, switchable, remembered in localStorage.
// One file per language (lang/<code>.js), fetched on demand (issue 19): the page's language
// before the first render (loadLang), the other one on the first switch (setLang). Both
// files hold the same keys (tests/web/test_fleet_live.py), so there is no fallback download.

const STORAGE_KEY = "kybercore.lang";
export const LANGS = ["en", "es"];
const listeners = new Set();
/** @type {Record<string, Record<string, string>>} the languages fetched so far */
const loaded = {};
/** @type {Record<string, Promise<Record<string, string>>>} */
const loading = {};
let lang = initialLang();
let wanted = lang; // the language of the latest setLang(), while it may still be loading

function initialLang() {
  let stored = null;
  try {
    stored = localStorage.getItem(STORAGE_KEY);
  } catch {
    stored = null;
  }
  if (stored && LANGS.includes(stored)) return stored;
  const browser = (navigator.languages && navigator.languages[0]) || navigator.language || "en";
  return browser.toLowerCase().startsWith("es") ? "es" : "en";
}

/** The strings of `code`, imported once (relative to this module, so under the page's
 * versioned /static/v-<token>/ prefix). */
function fetchLang(code) {
  loading[code] ??= import(`./lang/${code}.js`).then(
    (module) => (loaded[code] = module.default),
    (error) => {
      delete loading[code]; // offline for a moment: the next switch tries again
      throw error;
    },
  );
  return loading[code];
}

/** Load the current language: fleet.js awaits it before the first render. */
export async function loadLang() {
  await fetchLang(lang);
}

export function getLang() {
  return lang;
}

/** A translated string; {name} placeholders are filled from vars. With vars.n === 1 the
 * key's "_one" form is used where there is one ("1 printer", "1 seleccionada"). */
export function t(key, vars) {
  /** @type {Record<string, string | undefined>} */
  const strings = loaded[lang] ?? {};
  const one = vars?.n === 1 ? strings[`${key}_one`] : undefined;
  const text = one ?? strings[key] ?? key;
  if (!vars) return text;
  return text.replace(/\{(\w+)\}/g, (match, name) => (name in vars ? String(vars[name]) : match));
}

/** Switch to `next`, fetching its file on the first switch; the listeners run once its
 * strings are there. Of quick successive switches, the last one wins. */
export async function setLang(next) {
  if (!LANGS.includes(next) || next === wanted) return;
  wanted = next;
  try {
    await fetchLang(next);
  } catch (error) {
    if (wanted === next) wanted = lang; // the page stays in its language
    throw error;
  }
  if (wanted !== next || next === lang) return; // switched again meanwhile
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
