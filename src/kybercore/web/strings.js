// Every label of the dashboard, in English and Spanish. Keys must match in both.
import { en } from "./strings_en.js";
import { es } from "./strings_es.js";
import { ledger } from "./strings_ledger.js";
import { notify } from "./strings_notify.js";
import { printerPage } from "./strings_printer.js";

export const STRINGS = {
  en: { ...en, ...ledger.en, ...notify.en, ...printerPage.en },
  es: { ...es, ...ledger.es, ...notify.es, ...printerPage.es },
};
