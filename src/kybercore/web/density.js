// Compact tiles: smaller tiles without thumbnails, badges or heater labels, so that 50
// printers fit on one 1080p screen. The choice is remembered (theme.js applies it before
// the first paint).
import { t } from "./i18n.js";

const KEY = "kybercore.density";

/** Wire the toggle `button`; call again (relabel) after a language change. */
export function initDensity(button) {
  const root = document.documentElement;
  const label = () => {
    const compact = root.dataset.density === "compact";
    button.setAttribute("aria-pressed", String(compact));
    button.querySelector("span").textContent = t("density.compact");
    button.title = t(compact ? "density.to_comfortable" : "density.to_compact");
  };
  if (!button.dataset.wired) {
    button.dataset.wired = "1";
    button.addEventListener("click", () => {
      root.dataset.density = root.dataset.density === "compact" ? "comfortable" : "compact";
      try {
        localStorage.setItem(KEY, root.dataset.density);
      } catch {
        // private mode: the choice lasts for this page only
      }
      label();
    });
  }
  label();
}
