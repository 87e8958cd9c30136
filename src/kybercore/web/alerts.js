// Alerts beyond the page: a browser notification (the Notification API, opt-in) when the
// page is hidden or not focused, and an optional sound, for prints that finish or fail and
// printers that stop. Fed by the same live transitions as the toasts, so a reconnect or a
// page load never alerts about the past. Both choices are remembered per browser.
import { h, setText } from "./dom.js";
import { t } from "./i18n.js";

const KEYS = { notify: "kybercore.alerts.notify", sound: "kybercore.alerts.sound" };
// Two tones per kind: rising for a finished print, falling and lower for trouble.
const TONES = { ok: [660, 880], error: [440, 220] };

let buttons = null;
let audio = null;

/** Wire the two toggles (browser notifications, sound); call again to relabel. */
export function initAlerts(notifyButton, soundButton) {
  if (!buttons) {
    buttons = { notify: notifyButton, sound: soundButton };
    notifyButton.addEventListener("click", toggleNotifications);
    soundButton.addEventListener("click", () => {
      save("sound", !enabled("sound"));
      if (enabled("sound")) beep("ok"); // a sample, and the user's click unlocks audio
      label();
    });
  }
  notifyButton.hidden = !("Notification" in window);
  label();
}

/** Tell the operator: `kind` "ok" (a print finished) or "error" (failed, stopped). */
export function alertOperator({ kind, title, message }) {
  if (enabled("sound")) beep(kind);
  const away = document.hidden || !document.hasFocus();
  if (!away || !enabled("notify") || !("Notification" in window) || Notification.permission !== "granted") return;
  // One notification per printer and kind: a newer one replaces the older (tag).
  new Notification(title, { body: message, tag: `kybercore-${title}-${kind}` });
}

async function toggleNotifications() {
  if (enabled("notify")) {
    save("notify", false);
  } else {
    const permission = Notification.permission === "default" ? await Notification.requestPermission() : Notification.permission;
    save("notify", permission === "granted");
    if (permission === "denied") buttons.notify.title = t("alerts.denied");
  }
  label();
}

function label() {
  for (const [key, button] of Object.entries(buttons)) {
    const on = enabled(key);
    button.setAttribute("aria-pressed", String(on));
    setText(button.querySelector("span") || button.appendChild(h("span")), t(`alerts.${key}`));
    if (key === "notify" && "Notification" in window && Notification.permission === "denied") button.title = t("alerts.denied");
    else button.title = t(on ? `alerts.${key}_off` : `alerts.${key}_on`);
  }
}

function enabled(key) {
  try {
    return localStorage.getItem(KEYS[key]) === "on";
  } catch {
    return false;
  }
}

function save(key, on) {
  try {
    localStorage.setItem(KEYS[key], on ? "on" : "off");
  } catch {
    // private mode: nothing to remember it in
  }
}

function beep(kind) {
  audio ||= new AudioContext();
  const start = audio.currentTime;
  (TONES[kind] || TONES.error).forEach((frequency, i) => {
    const tone = audio.createOscillator();
    const gain = audio.createGain();
    tone.frequency.value = frequency;
    gain.gain.setValueAtTime(0.15, start + i * 0.18);
    gain.gain.exponentialRampToValueAtTime(0.001, start + i * 0.18 + 0.16);
    tone.connect(gain).connect(audio.destination);
    tone.start(start + i * 0.18);
    tone.stop(start + i * 0.18 + 0.17);
  });
}
