// ESLint for the dashboard: plain ES modules in the browser, no build step.
import js from "@eslint/js";
import globals from "globals";

export default [
  { ignores: ["src/kybercore/web/vendor/**", "node_modules/**", ".venv/**"] },
  js.configs.recommended,
  {
    files: ["src/kybercore/web/theme.js"],
    languageOptions: { sourceType: "script" }, // a classic script in <head>, before paint
  },
  {
    files: ["src/kybercore/web/**/*.js"],
    languageOptions: { ecmaVersion: 2023, sourceType: "module", globals: globals.browser },
    rules: {
      // `const { q, ...kept } = view` leaves q out on purpose.
      "no-unused-vars": ["error", { args: "after-used", argsIgnorePattern: "^_", ignoreRestSiblings: true }],
      eqeqeq: ["error", "always"],
      "no-var": "error",
      "prefer-const": "error",
    },
  },
];
