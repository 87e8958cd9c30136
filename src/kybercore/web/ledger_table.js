// The paged tables of the ledger (History, Audit log): a title with a count, a row of
// filters, the table, and a pager. One request per page; the answer to an older request
// (filters typed fast) is dropped; an error shows where the rows would be.
import { ApiError } from "./api.js";
import { h, setText } from "./dom.js";
import { messageOf, t } from "./i18n.js";

const PAGE = 50;

/** A date input's day (YYYY-MM-DD) as the instant its local day starts, `plus` days later
 * (1: where a "to" filter ends, so the day itself is included); "" when none is set. */
export function localDay(value, plus) {
  if (!value) return "";
  const [y, m, d] = value.split("-").map(Number);
  return new Date(y, m - 1, d + plus).toISOString();
}

/**
 * @typedef {object} TableSpec
 * @property {string} id the view's prefix: the title is `<id>-title`
 * @property {string} [tableClass] a class of its own for the table, for the view's CSS
 * @property {Element[]} filters the controls over the table, in order
 * @property {Element[]} [actions] what the title row carries on its right (a download)
 * @property {(limit: number, offset: number) => Promise<{total: number, items: any[]}>} fetch
 * @property {(item: any) => HTMLTableRowElement} row
 * @property {string} keys the i18n prefix of `title`, `summary`, `summary_one`, `empty`
 *   and `col.<column>`
 * @property {string[]} columns
 */

export class LedgerTable {
  /**
   * Build the view into its (empty) section.
   * @param {HTMLElement} root
   * @param {TableSpec} spec
   */
  constructor(root, spec) {
    this.root = root;
    this.spec = spec;
    this.offset = 0;
    this.loaded = false;
    this.asked = 0;
    this.title = h("h2", { id: `${spec.id}-title` });
    this.summary = h("p", { class: "muted", "aria-live": "polite" });
    this.head = h("tr");
    this.rows = h("tbody");
    this.empty = h("p", { class: "empty", hidden: true });
    this.prev = h("button", { type: "button", class: "btn small", onclick: () => this.page(-1) });
    this.next = h("button", { type: "button", class: "btn small", onclick: () => this.page(1) });
    this.pageText = h("span", { class: "muted" });
    root.setAttribute("aria-labelledby", `${spec.id}-title`);
    root.append(
      h("header", { class: "ledger-head" }, this.title, this.summary, h("span", { class: "toolbar-spacer" }), spec.actions || []),
      h("div", { class: "toolbar ledger-filters" }, spec.filters),
      // Focusable: a table wider than the screen scrolls, and keyboards must reach it.
      h(
        "div",
        { class: "table-wrap", tabindex: "0", role: "region", "aria-labelledby": `${spec.id}-title` },
        h(
          "table",
          { class: ["fleet-table ledger-table", spec.tableClass].filter(Boolean).join(" ") },
          h("thead", {}, this.head),
          this.rows,
        ),
      ),
      this.empty,
      h("nav", { class: "pager" }, this.prev, this.pageText, this.next),
    );
  }

  /** The title, pager and column labels in the current language; the rows again in it. */
  relabel() {
    const { keys, columns } = this.spec;
    setText(this.title, t(`${keys}.title`));
    setText(this.prev, t("ledger.prev"));
    setText(this.next, t("ledger.next"));
    this.head.replaceChildren(...columns.map((c) => h("th", { scope: "col" }, t(`${keys}.col.${c}`))));
    if (this.loaded) this.load();
  }

  /** The filters changed: back to the first page. */
  reload() {
    this.offset = 0;
    this.load();
  }

  page(step) {
    this.offset = Math.max(0, this.offset + step * PAGE);
    this.load();
  }

  /** Ask for the current page and show it (or why it could not be read). */
  async load() {
    const mine = ++this.asked;
    this.root.setAttribute("aria-busy", "true");
    let answer;
    try {
      answer = await this.spec.fetch(PAGE, this.offset);
    } catch (error) {
      if (mine !== this.asked) return;
      this.root.removeAttribute("aria-busy");
      this.rows.replaceChildren();
      this.empty.hidden = false;
      setText(this.empty, error instanceof ApiError ? messageOf(error) : t("error.unknown"));
      return;
    }
    if (mine !== this.asked) return;
    this.loaded = true;
    this.root.removeAttribute("aria-busy");
    const { total, items } = answer;
    const { keys } = this.spec;
    this.rows.replaceChildren(...items.map(this.spec.row));
    this.empty.hidden = items.length > 0;
    setText(this.empty, t(`${keys}.empty`));
    setText(this.summary, t(total === 1 ? `${keys}.summary_one` : `${keys}.summary`, { total }));
    const first = items.length ? this.offset + 1 : 0;
    setText(this.pageText, t("ledger.page", { first, last: this.offset + items.length, total }));
    this.prev.disabled = this.offset === 0;
    this.next.disabled = this.offset + items.length >= total;
    this.root.dataset.total = String(total);
  }
}
