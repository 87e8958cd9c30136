// Accessible modals (native <dialog>: focus kept inside, Escape closes, focus returns to the
// opener), confirmations, toasts in a live region, and a keyboard-driven popup menu.
import { byId, h, icon } from "./dom.js";
import { t } from "./i18n.js";

let counter = 0;

/**
 * @typedef {object} DialogButton
 * @property {string} label
 * @property {string} [value]
 * @property {string} [kind] "primary", "danger", "danger ghost" or nothing
 * @property {boolean} [cancel]
 */

/**
 * Open a modal. buttons: [{label, value, kind: "primary"|"danger"|"", cancel}]; the
 * promise resolves with the value of the button used (null when dismissed).
 * onSubmit(value, form) may run work with the dialog open: return false to keep it open
 * (e.g. to show validation messages), anything else closes it with that value.
 * @param {{title: string, body: Node | string, buttons?: DialogButton[], wide?: boolean,
 *   onSubmit?: (value: string, form: HTMLFormElement) => any, focus?: string}} options
 *   focus: a selector, inside the dialog, for what gets the focus first
 * @returns {Promise<any>}
 */
export function modal({ title, body, buttons = [], onSubmit, wide = false, focus }) {
  return new Promise((resolve) => {
    const opener = /** @type {HTMLElement | null} */ (document.activeElement);
    const titleId = `dialog-title-${++counter}`;
    let busy = false;
    const footer = h("footer", { class: "dialog-actions" });
    const form = h(
      "form",
      { class: "dialog-form", novalidate: true },
      h(
        "header",
        { class: "dialog-head" },
        h("h2", { id: titleId, text: title }),
        h("button", { type: "button", class: "icon-btn", "aria-label": t("action.close_dialog"), onclick: () => finish(null) }, icon("close")),
      ),
      h("div", { class: "dialog-body" }, body),
      footer,
    );
    const dialog = h("dialog", { class: `dialog${wide ? " wide" : ""}`, "aria-labelledby": titleId }, form);
    /** @type {HTMLButtonElement | null} */
    let defaultButton = null;
    for (const spec of buttons) {
      const button = h("button", {
        type: spec.cancel ? "button" : "submit",
        class: `btn ${spec.kind || ""}`.trim(),
        value: spec.value ?? "",
        text: spec.label,
      });
      if (spec.cancel) button.addEventListener("click", () => finish(null));
      if (!spec.cancel && !defaultButton) defaultButton = button;
      footer.append(button);
    }
    form.addEventListener("submit", async (event) => {
      event.preventDefault();
      if (busy) return;
      const submitter = /** @type {HTMLButtonElement | null} */ (event.submitter) || defaultButton;
      const value = submitter ? submitter.value : "";
      if (!onSubmit) return finish(value);
      busy = true;
      dialog.setAttribute("aria-busy", "true");
      const controls = [...footer.querySelectorAll("button")];
      for (const button of controls) button.disabled = true;
      let result;
      try {
        result = await onSubmit(value, form);
      } finally {
        busy = false;
        dialog.removeAttribute("aria-busy");
        for (const button of controls) button.disabled = false;
      }
      if (result !== false) finish(result === undefined ? value : result);
    });
    dialog.addEventListener("cancel", (event) => {
      event.preventDefault();
      if (!busy) finish(null);
    });

    function finish(value) {
      if (!dialog.open) return;
      dialog.close();
      dialog.remove();
      if (opener && opener.isConnected && typeof opener.focus === "function") opener.focus();
      resolve(value);
    }

    document.body.append(dialog);
    dialog.showModal();
    /** @param {string} selector */
    const find = (selector) => /** @type {HTMLElement | null} */ (form.querySelector(selector));
    const first = (focus && find(focus)) || find("[autofocus], .dialog-body input, .dialog-body select, .dialog-body textarea");
    (first || footer.querySelector("button") || form).focus();
  });
}

/**
 * Ask before something drastic. Resolves true when confirmed. Cancel has the focus.
 * @param {{title: string, message: string, confirmLabel: string, danger?: boolean, details?: any[]}} options
 * @returns {Promise<boolean>}
 */
export async function confirmDialog({ title, message, confirmLabel, danger = false, details = [] }) {
  const body = h(
    "div",
    {},
    h("p", { class: "confirm-message", text: message }),
    details.length ? h("ul", { class: "reason-list" }, details.map((d) => h("li", { class: `reason ${d.level || ""}`, text: d.text }))) : null,
  );
  const value = await modal({
    title,
    body,
    buttons: [
      { label: t("action.back"), cancel: true },
      { label: confirmLabel, value: "yes", kind: danger ? "danger" : "primary" },
    ],
    focus: ".dialog-actions button",
  });
  return value === "yes";
}

// -- toasts ---------------------------------------------------------------------------------

/**
 * A short message in the live region; errors stay until closed.
 * @param {{kind?: string, title?: string, message?: string, timeout?: number}} options
 */
export function toast({ kind = "info", title = "", message = "", timeout }) {
  const region = byId("toasts");
  keepAboveBulkBar(region);
  const item = h(
    "div",
    { class: `toast ${kind}`, role: kind === "error" ? "alert" : "status" },
    h("span", { class: "toast-icon" }, icon(kind === "ok" ? "check" : kind === "info" ? "bolt" : "alert")),
    h("div", { class: "toast-text" }, title ? h("strong", { text: title }) : null, h("span", { text: message })),
    h("button", { type: "button", class: "icon-btn", "aria-label": t("action.dismiss"), onclick: () => item.remove() }, icon("close")),
  );
  region.append(item);
  while (region.children.length > 6) region.firstElementChild?.remove();
  const ms = timeout ?? (kind === "error" ? 15000 : 6000);
  if (ms > 0) setTimeout(() => item.remove(), ms);
  return item;
}

let bulkBarWatch = null;

/** Lift the toasts above the bulk bar while it is shown, so they never cover its buttons. */
function keepAboveBulkBar(region) {
  const bar = document.getElementById("bulk");
  if (bulkBarWatch || !bar || typeof ResizeObserver === "undefined") return;
  const place = () => {
    const rect = bar.getBoundingClientRect();
    // Hidden, the bar has no box; shown, it may wrap to several rows (phones).
    region.style.bottom = rect.height ? `${Math.ceil(window.innerHeight - rect.top) + 8}px` : "";
  };
  bulkBarWatch = new ResizeObserver(place);
  bulkBarWatch.observe(bar);
  window.addEventListener("resize", place);
  place();
}

// -- popup menu ------------------------------------------------------------------------------

let openMenuState = null;

/** A menu under `anchor`: items [{label, icon, disabled, danger, onSelect}]. */
export function openMenu(anchor, items, label) {
  closeMenu();
  const menu = h("div", { class: "menu", role: "menu", "aria-label": label });
  for (const item of items) {
    if (item.separator) {
      menu.append(h("div", { class: "menu-sep", role: "separator" }));
      continue;
    }
    const entry = h(
      "button",
      {
        type: "button",
        role: "menuitem",
        class: `menu-item${item.danger ? " danger" : ""}`,
        disabled: item.disabled,
        "aria-disabled": item.disabled ? "true" : null,
        tabindex: "-1",
        onclick: () => {
          // Focus back on the menu's button first: a dialog the item opens returns focus
          // to what had it (this item is gone by then), not to the page body.
          closeMenu();
          item.onSelect();
        },
      },
      item.icon ? icon(item.icon) : null,
      h("span", { text: item.label }),
    );
    menu.append(entry);
  }
  document.body.append(menu);
  const rect = anchor.getBoundingClientRect();
  const width = menu.offsetWidth;
  const height = menu.offsetHeight;
  const left = Math.max(8, Math.min(rect.right - width, window.innerWidth - width - 8));
  const below = rect.bottom + 4 + height < window.innerHeight;
  menu.style.left = `${left}px`;
  menu.style.top = `${below ? rect.bottom + 4 : Math.max(8, rect.top - height - 4)}px`;
  anchor.setAttribute("aria-expanded", "true");
  const entries = () => [.../** @type {NodeListOf<HTMLElement>} */ (menu.querySelectorAll(".menu-item:not([disabled])"))];
  menu.addEventListener("keydown", (event) => {
    const list = entries();
    const index = list.indexOf(/** @type {HTMLElement} */ (document.activeElement));
    const moves = { ArrowDown: index + 1, ArrowUp: index - 1, Home: 0, End: list.length - 1 };
    if (event.key in moves) {
      event.preventDefault();
      list[(moves[event.key] + list.length) % list.length]?.focus();
    } else if (event.key === "Escape") {
      event.preventDefault();
      closeMenu();
    } else if (event.key === "Tab") {
      closeMenu();
    }
  });
  const outside = (event) => {
    if (!menu.contains(event.target) && event.target !== anchor && !anchor.contains(event.target)) closeMenu(false);
  };
  setTimeout(() => document.addEventListener("pointerdown", outside), 0);
  openMenuState = { menu, anchor, outside };
  entries()[0]?.focus();
}

export function closeMenu(refocus = true) {
  if (!openMenuState) return;
  const { menu, anchor, outside } = openMenuState;
  openMenuState = null;
  document.removeEventListener("pointerdown", outside);
  menu.remove();
  anchor.setAttribute("aria-expanded", "false");
  if (refocus && anchor.isConnected) anchor.focus();
}

export function menuIsOpenFor(anchor) {
  return openMenuState !== null && openMenuState.anchor === anchor;
}
