// Theme and tile density before the first paint (a classic script in <head>, not a
// module): the stored choice, else the system's theme and comfortable tiles. The toggles
// live in fleet.js and density.js.
(function () {
  let dark = false;
  let compact = false;
  try {
    const saved = localStorage.getItem("kybercore.theme");
    dark = saved ? saved === "dark" : matchMedia("(prefers-color-scheme: dark)").matches;
    compact = localStorage.getItem("kybercore.density") === "compact";
  } catch {
    dark = false;
  }
  document.documentElement.dataset.theme = dark ? "dark" : "light";
  document.documentElement.dataset.density = compact ? "compact" : "comfortable";
})();
