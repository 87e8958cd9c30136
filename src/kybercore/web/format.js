// Numbers, sizes, durations and dates in the UI's language.
import { getLang, t } from "./i18n.js";

const numberFormats = new Map();

function number(value, digits) {
  const key = `${getLang()}|${digits}`;
  if (!numberFormats.has(key)) {
    numberFormats.set(
      key,
      new Intl.NumberFormat(getLang(), { minimumFractionDigits: digits, maximumFractionDigits: digits }),
    );
  }
  return numberFormats.get(key).format(value);
}

/** 205.1 -> "205.1°"; unknown -> "—". */
export function temp(value) {
  return typeof value === "number" ? `${number(value, 1)}°` : "—";
}

/** A heater target: "205°", or "off" when 0. */
export function target(value) {
  if (typeof value !== "number") return "";
  return value > 0 ? `${number(value, 0)}°` : t("temp.off");
}

export function percent(fraction) {
  const value = Math.floor((fraction || 0) * 100);
  return getLang() === "es" ? `${value} %` : `${value}%`;
}

/** 3725 -> "1 h 02 min"; 75 -> "1 min 15 s"; 40 -> "40 s". */
export function duration(seconds) {
  if (typeof seconds !== "number" || !Number.isFinite(seconds) || seconds < 0) return "—";
  const s = Math.round(seconds);
  const hours = Math.floor(s / 3600);
  const minutes = Math.floor((s % 3600) / 60);
  if (hours >= 24) return `${Math.floor(hours / 24)} d ${hours % 24} h`;
  if (hours) return `${hours} h ${String(minutes).padStart(2, "0")} min`;
  if (minutes >= 10) return `${minutes} min`;
  if (minutes) return `${minutes} min ${s % 60} s`;
  return `${s} s`;
}

/** How old something is, short: "23 s", "4 min", "2 h". */
export function age(seconds) {
  const s = Math.max(0, Math.round(seconds));
  if (s < 60) return `${s} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min`;
  if (s < 86400) return `${Math.floor(s / 3600)} h`;
  return `${Math.floor(s / 86400)} d`;
}

export function size(bytes) {
  if (typeof bytes !== "number") return "—";
  const units = ["B", "KB", "MB", "GB"];
  let value = bytes;
  let unit = 0;
  while (value >= 1024 && unit < units.length - 1) {
    value /= 1024;
    unit += 1;
  }
  return `${number(value, unit === 0 ? 0 : 1)} ${units[unit]}`;
}

/** Unix seconds -> a short local date and time. */
export function dateTime(unix) {
  if (typeof unix !== "number") return "—";
  return new Intl.DateTimeFormat(getLang(), { dateStyle: "short", timeStyle: "short" }).format(unix * 1000);
}

/** Unix seconds -> local clock time, "14:32". */
export function clock(unix) {
  return new Intl.DateTimeFormat(getLang(), { hour: "2-digit", minute: "2-digit" }).format(unix * 1000);
}

/**
 * When something will be done, as a local clock time: { time: "15:42" } today, else with the
 * day too: { day: "Tue", time: "09:10" } within a week, { day: "3 Dec", time } after that.
 * `unix` is in this browser's clock.
 */
export function finish(unix, now = Date.now() / 1000) {
  const time = clock(unix);
  const midnight = (seconds) => new Date(seconds * 1000).setHours(0, 0, 0, 0);
  const days = Math.round((midnight(unix) - midnight(now)) / 86_400_000);
  if (days === 0) return { day: "", time };
  /** @type {Intl.DateTimeFormatOptions} */
  const options = days > 0 && days < 7 ? { weekday: "short" } : { day: "numeric", month: "short" };
  return { day: new Intl.DateTimeFormat(getLang(), options).format(unix * 1000), time };
}

/**
 * "done at 15:42" / "termina a las 15:42" for a job with an `eta_at`, or "". `eta_at` is
 * the server's clock: `serverNowSeconds` (the server's now) moves it onto this browser's.
 */
export function doneText(job, serverNowSeconds) {
  if (typeof job?.eta_at !== "number") return "";
  const { day, time } = finish(job.eta_at - (serverNowSeconds - Date.now() / 1000));
  return day ? t("job.done_on", { day, time }) : t("job.done_at", { time });
}

/** The part after the last "/", for long file paths. */
export function baseName(path) {
  return (path || "").split("/").pop();
}
