// Theme before the first paint (a classic script in <head>, not a module): the stored
// choice, else the system's. The toggle itself lives in fleet.js.
(function () {
  let dark = false;
  try {
    const saved = localStorage.getItem("kybercore.theme");
    dark = saved ? saved === "dark" : matchMedia("(prefers-color-scheme: dark)").matches;
  } catch {
    dark = false;
  }
  document.documentElement.dataset.theme = dark ? "dark" : "light";
})();
