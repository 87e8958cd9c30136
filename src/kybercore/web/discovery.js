// "Find printers": the Moonraker servers announcing themselves on the network (mDNS, the
// [zeroconf] section of moonraker.conf), each with one button to add it. Adding goes
// through the same validated route as the form, with its connection test; typing an
// address in "Add printer" stays the main path (mDNS does not cross routers or VLANs).
import { api } from "./api.js";
import { modal, toast } from "./dialogs.js";
import { h, setText } from "./dom.js";
import { messageOf, t } from "./i18n.js";
import { printers } from "./store.js";

const LISTEN_SECONDS = 3;

/** Open the dialog and start listening. */
export async function findPrinters() {
  const status = h("p", { class: "find-status", role: "status", "aria-live": "polite", text: t("find.listening", { n: LISTEN_SECONDS }) });
  const list = h("ul", { class: "find-list" });
  const again = h("button", { type: "button", class: "btn small", text: t("find.again"), disabled: true, onclick: () => listen() });
  const body = h("div", { class: "find-body" }, h("p", { class: "muted", text: t("find.intro") }), status, list, again);

  async function listen() {
    again.disabled = true;
    list.replaceChildren();
    list.setAttribute("aria-busy", "true");
    setText(status, t("find.listening", { n: LISTEN_SECONDS }));
    try {
      const found = await api.discover(LISTEN_SECONDS);
      list.replaceChildren(...found.map(row));
      setText(status, found.length ? t("find.found", { n: found.length }) : t("find.none"));
    } catch (error) {
      setText(status, messageOf(error));
    } finally {
      list.removeAttribute("aria-busy");
      again.disabled = false;
    }
  }

  listen();
  await modal({ title: t("find.title"), body, wide: true, buttons: [{ label: t("action.close"), cancel: true }] });
}

function row(found) {
  const where = h("span", { class: "find-where", text: `${found.url} · Moonraker ${found.version || "?"}` });
  const outcome = h("span", { class: "find-outcome", role: "status" });
  const li = h("li", { class: "find-item", dataset: { url: found.url } }, h("div", { class: "find-text" }, h("strong", { text: found.name }), where), outcome);
  if (found.added_as) {
    setText(outcome, t("find.added_as", { id: found.added_as }));
    return li;
  }
  const add = h("button", {
    type: "button",
    class: "btn small primary",
    text: t("find.add"),
    "aria-label": t("find.add_named", { name: found.name }),
    onclick: async () => {
      add.disabled = true;
      setText(outcome, t("find.checking"));
      try {
        const created = await api.addPrinter({ id: freeId(found.suggested_id), name: found.suggested_id, moonraker_url: found.url }, { check: true });
        add.remove();
        setText(outcome, t("find.added_as", { id: created.id }));
        toast({ kind: "ok", title: created.name, message: t("form.added", { id: created.id }) });
      } catch (error) {
        add.disabled = false;
        setText(outcome, messageOf(error));
      }
    },
  });
  li.append(add);
  return li;
}

/** `id`, or `id-2`, `id-3`… when a printer already has it. */
function freeId(id) {
  let candidate = id;
  for (let n = 2; printers.has(candidate); n += 1) candidate = `${id}-${n}`;
  return candidate;
}
