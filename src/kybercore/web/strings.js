// Every label of the dashboard, in English and Spanish. Keys must match in both.
import { en } from "./strings_en.js";
import { es } from "./strings_es.js";

export const STRINGS = { en, es };
