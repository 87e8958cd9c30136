// The event kinds a channel can subscribe to, as the backend lists them (GET
// /api/notifications/kinds: kind, severity, labels in English and Spanish), fetched once.
import { api } from "./api.js";
import { getLang } from "./i18n.js";

export const SEVERITIES = ["critical", "warning", "info"];
// Test messages always reach a channel: nothing to subscribe to.
const ALWAYS = "test";

let kinds = [];
let loading = null;

/** Fetch the kinds (once; a failed fetch is tried again on the next call). */
export function loadKinds() {
  if (!loading) {
    loading = api.notifyKinds().then(
      (answer) => {
        kinds = answer.filter((k) => k.kind !== ALWAYS);
        return kinds;
      },
      (error) => {
        loading = null;
        throw error;
      },
    );
  }
  return loading;
}

/** The kinds a channel can pick, in the backend's order. */
export function selectableKinds() {
  return kinds;
}

/** A kind's label in the UI's language (its name when the backend did not list it). */
export function kindLabel(kind, lang = getLang()) {
  const known = kinds.find((k) => k.kind === kind);
  return (known && (known[lang] || known.en)) || kind;
}

/** The kinds a new channel starts with. */
export function defaultKinds() {
  return kinds.filter((k) => k.default).map((k) => k.kind);
}
